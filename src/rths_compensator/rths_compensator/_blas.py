"""Limit the BLAS thread pool to one thread for the small dense design problems.

Limit the BLAS thread pool: on small dense problems (the FIR designs, n <= 300) a
multi-threaded OpenBLAS on a loaded 2-core machine is several times SLOWER than one thread.
"""

import ctypes


def limit_blas_threads(n: int = 1) -> bool:
    """Set the number of OpenBLAS threads of this process; return True if it worked."""
    try:
        with open('/proc/self/maps', encoding='utf-8') as handle:
            libs = {line.split()[-1] for line in handle if 'openblas' in line.lower()
                    and line.split()[-1].startswith('/')}
    except OSError:
        return False
    done = False
    for lib in libs:
        try:
            dll = ctypes.CDLL(lib)
        except OSError:
            continue
        for name in ('scipy_openblas_set_num_threads64_', 'scipy_openblas_set_num_threads',
                     'openblas_set_num_threads64_', 'openblas_set_num_threads'):
            func = getattr(dll, name, None)
            if func is not None:
                func(int(n))
                done = True
                break
    return done
