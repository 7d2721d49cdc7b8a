"""Review of a recorded RTHS run from its bag alone: tables 5-9, real-time figures, report."""
