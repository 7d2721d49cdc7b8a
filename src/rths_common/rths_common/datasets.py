"""Where the real data sets are: ``$RTHS_DATA_DIR``, else ``../shared/data`` beside the repository.

The measured records that the tests of truth and the benchmarks compare with are public
data sets that the repository does not hold (it cites them).  :data:`DATASETS` names each
one: its folder under the data directory, the files that must be there, its source and
licence.  :func:`data_dir` is the one place that decides where they are looked for:

1. ``RTHS_DATA_DIR`` when the user sets it (it always wins);
2. else ``<repository>/../shared/data`` when that folder exists (a checkout with the
   project's shared folder beside it, as CI has it);
3. else nothing: :func:`dataset_dir` raises an OSError naming the data set and its source.
"""

from dataclasses import dataclass
import os
from pathlib import Path
from typing import Optional

DATA_ENV = 'RTHS_DATA_DIR'


@dataclass(frozen=True)
class Dataset:
    """One public data set: ``files`` are looked for in ``<data dir>/<folder>``."""

    title: str
    folder: str
    files: tuple
    source: str
    licence: str
    redistributable: bool = True


DATASETS = {
    'emps': Dataset(
        title='EMPS electro-mechanical positioning system (Janot, Gautier, Brunot)',
        folder='emps', files=('DATA_EMPS.mat', 'DATA_EMPS_PULSES.mat'),
        source='github.com/forgi86/sysid-neural-continuous, examples/EMPS/data',
        licence='Apache-2.0'),
    'mr_damper': Dataset(
        title='30 sinusoid tests of a real MR damper',
        folder='mr_damper', files=('2mm5Hz1A.txt', '10mm1Hz1A.txt', '25mm0x25Hz0x5A.txt'),
        source='github.com/DanielMaurelE/vRTHS_AMBC_MRdamper, Cap7_ModeloMR/BoucWen Ajuste 1/'
               'Preprocesamiento-sinusoidales/Preprocesados',
        licence='MIT, (c) 2022 mequiroz'),
    'f16gvt': Dataset(
        title='F-16 ground vibration test (Noel, Kerschen)',
        folder='f16gvt', files=('F16Data_FullMSine_Level1.csv',
                                'F16Data_SpecialOddMSine_Level1_Validation.csv'),
        source='github.com/forgi86/dynonet, examples/F16GVT/data',
        licence='MIT repository; data published for benchmarking by its authors'),
    'cascaded_tanks': Dataset(
        title='cascaded tanks with overflow (Schoukens, Mattsson, Wigren, Noel)',
        folder='cascaded_tanks', files=('dataBenchmark.csv',),
        source='github.com/forgi86/dynonet, examples/CTS/data',
        licence='MIT repository; data published for benchmarking by its authors'),
    'bouc_wen': Dataset(
        title='Bouc-Wen hysteretic benchmark, simulated (Noel, Schoukens)',
        folder='bouc_wen', files=('train.h5', 'test.h5', 'uval_multisine.mat',
                                  'yval_multisine.mat'),
        source='github.com/forgi86/dynonet, examples/BW/BoucWenFiles',
        licence='MIT repository; data published for benchmarking by its authors'),
    'silva2020_records': Dataset(
        title='ground-motion records of the RTHS benchmark (Silva et al. 2020)',
        folder='', files=('ElCentroAccelNoScaling.mat',),
        source='github.com/MECHS-RCN/BENCHMARKS, "RTHS code RT V23.zip"',
        licence='not redistributable', redistributable=False),
    'marths_records': Dataset(
        title='ground-motion records of the maRTHS benchmark (El Centro, Kobe, Morgan Hill)',
        folder='', files=('ElCentroAccelNoScaling.mat', 'KobeAccelNoScaling.mat',
                          'MorganAccelNoScaling.mat'),
        source='github.com/FermandoisLab/maRTHS-bmk-RoDeAC, maRTHS-bmk-RoDeAC/Support_files/'
               'Ground_motions (byte-identical to the files of "RTHS code RT V23.zip" of '
               'github.com/MECHS-RCN/BENCHMARKS)',
        licence='treated as silva2020_records (the same files): not redistributable',
        redistributable=False),
}


def repo_root() -> Optional[Path]:
    """Return the repository's root: ``$RTHS_ROOT`` (env.sh sets it), else found above here."""
    root = os.environ.get('RTHS_ROOT')
    if root:
        return Path(root)
    for parent in Path(__file__).resolve().parents:
        if (parent / 'env.sh').is_file() and (parent / 'src').is_dir():
            return parent
    return None


def default_data_dir() -> Optional[Path]:
    """Return ``<repository>/../shared/data`` when that folder exists, else None."""
    root = repo_root()
    if root is None:
        return None
    path = (root / '..' / 'shared' / 'data').resolve()
    return path if path.is_dir() else None


def data_dir() -> Optional[Path]:
    """Return the data directory: ``$RTHS_DATA_DIR`` if set, else :func:`default_data_dir`."""
    own = os.environ.get(DATA_ENV)
    return Path(own) if own else default_data_dir()


def where() -> str:
    """Say where the data sets are looked for (for messages)."""
    own = os.environ.get(DATA_ENV)
    if own:
        return f'{DATA_ENV}={own}'
    root = repo_root()
    shared = f'{root / ".." / "shared" / "data"}' if root else '../shared/data'
    return f'{shared} ({DATA_ENV} unset)'


def missing(name: str) -> Optional[str]:
    """Return None when data set ``name`` is there, else a one-line reason and how to fix it."""
    ds = DATASETS[name]
    base = data_dir()
    folder = base / ds.folder if base is not None else None
    absent = [f for f in ds.files if folder is None or not (folder / f).is_file()]
    if not absent:
        return None
    target = f'DIR/{ds.folder}/' if ds.folder else 'DIR/'
    shared = ", or put the project's shared/ folder beside the repository" \
        if ds.redistributable else ''
    return (f"data set '{name}' ({ds.title}) missing: no {absent[0]} under {where()}; "
            f'get it from {ds.source} ({ds.licence}) into {target} and set '
            f'{DATA_ENV}=DIR{shared}')


def dataset_dir(name: str) -> Path:
    """Return the folder of data set ``name`` (OSError with :func:`missing`'s reason if absent)."""
    reason = missing(name)
    base = data_dir()
    if reason or base is None:
        raise OSError(reason)
    return base / DATASETS[name].folder
