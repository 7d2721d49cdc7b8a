"""The bag as a test's evidence: its integrity, completeness and provenance (``rths bag verify``).

:func:`verify` reads a bag without changing it and returns a report:

* ``integrity``: :func:`rths_common.bagstore.check_integrity` (MCAP: the CRC-32
  of every chunk; sqlite3: ``PRAGMA integrity_check``) and whether the data file
  was closed; a file a killed recorder left open is not read (reading would
  repair it): ``rths bag repair`` first;
* ``completeness``: every step of every loop topic present or accounted for.
  The bridge writes a measurement and a status every tick: all of them must be
  there (:func:`bag_missing`). The interface displacements and commands go
  through the review's step alignment (:func:`rths_review.tracking.aligned_steps`):
  re-sends and short gaps are counted (at most MAX_FILLED_PCT of the steps,
  none longer than MAX_GAP_S, not at the start); longer gaps make the bag
  incomplete (the review still reviews it and states them). A run that stopped
  early says why (a safety stop, or a recording recovered after a crash,
  ``reindexed``);
* ``provenance``: rths version, git commit, host and the files the bag carries
  (:mod:`rths_common.provenance`).

``problems`` lists, one line each, what makes the bag fail (empty: the bag is
whole and complete).
"""

from pathlib import Path

from rths_common import bagio, bagstore, provenance, topics

#: Gaps of the interface displacements and commands a complete bag may have (the review
#: fills them linearly): at most this share of the steps [%] ...
MAX_FILLED_PCT = 1.0
#: ... none longer than this [s], and none at step 0.
MAX_GAP_S = 0.05


def bag_missing(summary: dict) -> list:
    """Return what a run's bag lacks: the bridge writes a measurement and a status every tick.

    ``summary`` is :func:`rths_review.review.loop_summary`'s; returns one text
    per incomplete stream (empty: every tick the bridge ran is in the bag).
    (Commands and interface displacements may be missing by design: lost or
    dropped ones are deadline misses, counted in the status.)
    """
    status = summary.get('status bridge', {})
    meas = summary.get(topics.MEASUREMENT, {})
    ticks = max(int(status.get('steps', 0)), (meas.get('last') or -1) + 1)
    out = []
    if int(status.get('steps', 0)) < ticks:
        out.append(f"the bridge status of {ticks - int(status.get('steps', 0))} of {ticks} "
                   'ticks is not in the bag')
    if int(meas.get('count', 0)) - int(meas.get('duplicates', 0)) < ticks:
        lost = ticks - int(meas.get('count', 0)) + int(meas.get('duplicates', 0))
        out.append(f'{topics.MEASUREMENT} lacks {lost} of {ticks} steps (the recorder lost '
                   'them)')
    return out


def verify(bag) -> dict:
    """Return the verification report of a bag (module doc); never changes the bag."""
    bag = bagio.bag_dir(bag)
    if not bag.is_dir():
        raise OSError(f'bag directory {bag} does not exist')
    report: dict = {'bag': str(bag), 'problems': []}
    problems = report['problems']
    integrity = report['integrity'] = bagstore.check_integrity(bag)
    if integrity['storage'] == 'mcap':
        if integrity['bad_chunks']:
            problems.append(f"{len(integrity['bad_chunks'])} of {integrity['chunks']} chunks "
                            'fail their CRC-32 (first at byte '
                            f"{integrity['bad_chunks'][0]}): the data were changed after writing")
        if not integrity['closed'] or not (bag / 'metadata.yaml').exists():
            problems.append("the recording was cut (its writer was killed): run 'rths bag "
                            f"repair {bag}' to recover it up to its last complete chunk")
            return report
    elif not (bag / 'metadata.yaml').exists():
        problems.append("the recording was cut (its writer was killed): run 'rths bag "
                        f"repair {bag}' to rebuild its metadata.yaml")
        return report
    elif not integrity['ok']:
        problems.append(f"the sqlite3 database fails its integrity check: {integrity['result']}")
    info = bagio.run_info(bag)
    report['provenance'] = _provenance(info)
    if not report['provenance'].get('rths_version'):
        report['notes'] = ['no provenance in the run information (recorded before rths kept it)']
    try:
        report['completeness'] = completeness(bag, info)
    except bagio.BagDamaged as err:
        problems.append(str(err))
        return report
    problems.extend(report['completeness'].pop('problems'))
    return report


def _provenance(info: dict) -> dict:
    prov = provenance.of_run_info(info)
    prov['files'] = {name: entry.get('sha256', '') for name, entry in prov['files'].items()}
    return prov


def completeness(bag: Path, info: dict) -> dict:
    """Return the steps of every loop topic present or accounted for (module doc), problems."""
    # lazy: start-up cost: the review imports SciPy and the numerical package
    from rths_review.review import loop_summary
    from rths_review.tracking import STEP_TOPICS, aligned_steps

    summary = loop_summary(bag)
    problems = bag_missing(summary)
    fs = float(info.get('fs_hz', 1024.0) or 1024.0)
    out: dict = {'topics': {}}
    for topic, (field, _) in STEP_TOPICS.items():
        entry = {k: summary[topic][k] for k in ('count', 'first', 'last', 'gaps', 'duplicates')}
        if topic != topics.MEASUREMENT and entry['count']:
            try:
                _, repairs = aligned_steps(bagio.step_arrays(bag, topic, (field,)), (field,),
                                           fs, f'{topic}')
            except ValueError as err:
                problems.append(str(err).split(';')[0])
            else:
                seen = repairs.pop('recorded')
                entry.update(repairs)
                longest = repairs['longest_gap_steps']
                if repairs['filled'] and (100.0 * repairs['filled'] / seen.size > MAX_FILLED_PCT
                                          or longest > MAX_GAP_S * fs or not seen[0]):
                    problems.append(f"{topic}: {repairs['filled']} missing steps in "
                                    f"{repairs['gaps']} gap(s), the longest {longest} steps "
                                    f'(more than {MAX_FILLED_PCT:g} % or a gap over '
                                    f'{MAX_GAP_S:g} s): the recording is incomplete')
        out['topics'][topic] = entry
    status = summary.get('status bridge', {})
    ticks = int(status.get('steps', 0))
    out['bridge_ticks'] = ticks
    out['deadline_misses'] = status.get('deadline_misses')
    out['final_safety_state'] = status.get('final_safety_state')
    duration = info.get('numerical.duration_s')
    planned = int(round(float(duration) * fs)) if duration not in (None, '') else None
    out['planned_steps'] = planned
    out['recovered_after_crash'] = str(info.get('reindexed', '')).lower() == 'true'
    if not ticks:
        problems.append('no bridge tick recorded: not a run bag, or the run never started')
    if out['recovered_after_crash']:
        problems.append(f'the recording was recovered after a crash: complete up to bridge tick '
                        f'{ticks} only')
    elif planned and ticks < planned and not status.get('final_safety_state'):
        out['note'] = f'the run stopped at tick {ticks} of {planned} without a safety stop'
    out['problems'] = problems
    return out


def repair(bag) -> dict:
    """Recover a cut recording up to its last complete chunk; return what the bag now holds.

    A bag whose data file is closed and whose ``metadata.yaml`` reads is left
    untouched (``repaired`` False). Otherwise :func:`rths_common.bagio.reindex`
    cuts the MCAP file after its last complete record, closes it and rebuilds
    ``metadata.yaml`` (sqlite3: rolls back the uncommitted transaction and
    rebuilds it). Returns ``{'repaired', 'topics': {topic: count}, 'last_step'}``.
    """
    bag = bagio.bag_dir(bag)
    if not bag.is_dir():
        raise OSError(f'bag directory {bag} does not exist')
    storage = bagstore.storage_of(bag)
    whole = (bag / 'metadata.yaml').exists() and (
        storage != 'mcap' or bagstore.is_complete(bagstore.data_file(bag)))
    if whole:
        try:
            bagio.metadata(bag)
        except ValueError:
            whole = False
    if not whole:
        bagio.reindex(bag)
    counts = {topic: entry['count'] for topic, entry in bagio.info(bag)['topics'].items()
              if entry['count']}
    steps = bagio.step_arrays(bag, topics.MEASUREMENT, ())['step']
    return {'repaired': not whole, 'topics': counts,
            'last_step': int(steps.max()) if steps.size else None}


def print_report(report: dict) -> None:
    """Print :func:`verify`'s report as text, ending with OK or the problems."""
    print(f"bag: {report['bag']}")
    i = report['integrity']
    if i['storage'] == 'mcap':
        print(f"integrity (mcap, CRC-32 per chunk): {i['chunks']} chunks, {i['chunks_checked']} "
              f"checked, {i['chunks_without_crc']} without a CRC, {len(i['bad_chunks'])} bad; "
              f"file {'closed' if i['closed'] else 'NOT closed'}"
              + (f", {i['tail_bytes']} bytes of a cut record at its end" if i['tail_bytes']
                 else ''))
    else:
        print(f"integrity (sqlite3, {i['check']}): {i['result']}")
    prov = report.get('provenance')
    if prov:
        print(f"provenance: rths {prov.get('rths_version') or '?'}, commit "
              f"{prov.get('git_commit') or '?'}, host {prov.get('host') or '?'}, recorded "
              f"{prov.get('recorded_utc') or '?'}; files: "
              f"{', '.join(prov['files']) or 'none'}")
    comp = report.get('completeness')
    if comp:
        print(f"completeness: {comp['bridge_ticks']} bridge ticks"
              + (f" of {comp['planned_steps']} planned" if comp['planned_steps'] else '')
              + f", deadline misses {comp['deadline_misses']}, final safety state "
              f"{comp['final_safety_state']}")
        for topic, e in comp['topics'].items():
            extra = ''.join(f", {k} {e[k]}" for k in ('resent', 'filled') if k in e)
            print(f"  {topic}: {e['count']} messages, steps {e['first']}-{e['last']}, "
                  f"gaps {e['gaps']}, duplicates {e['duplicates']}{extra}")
        if comp.get('note'):
            print(f"  note: {comp['note']}")
    for note in report.get('notes', []):
        print(f'note: {note}')
    if report['problems']:
        for text in report['problems']:
            print(f'BAG NOT OK: {text}')
    else:
        print('OK: the bag is whole (every checksum matches) and complete')
