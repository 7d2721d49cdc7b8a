"""Writing result files so that a failure never leaves a half-written one.

Every command of the project writes its outputs (parameter files, plant
models, JSON, CSV, plots) through :func:`atomic_open`: the data goes to a
temporary file beside the target, which replaces the target only once it is
complete; on an error the temporary file is removed and the old target, if
any, is untouched.
"""

from contextlib import contextmanager
import os
import tempfile


@contextmanager
def atomic_open(path, mode: str = 'w', suffix: str = '.tmp'):
    """Yield a file object whose content replaces ``path`` when the block ends without error.

    ``mode`` is 'w' (text, UTF-8) or 'wb'; missing parent directories are created.
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.' + os.path.basename(path) + '-', suffix=suffix,
                               dir=directory)
    try:
        with os.fdopen(fd, mode, encoding=None if 'b' in mode else 'utf-8') as handle:
            yield handle
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_figure(fig, path, **savefig_kwargs):
    """``fig.savefig`` to ``path`` atomically (the format follows the file name)."""
    suffix = os.path.splitext(os.fspath(path))[1] or '.png'
    with atomic_open(path, 'wb', suffix=suffix) as handle:
        fig.savefig(handle, format=suffix.lstrip('.'), **savefig_kwargs)
