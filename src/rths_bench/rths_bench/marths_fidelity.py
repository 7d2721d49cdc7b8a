"""Port fidelity of the maRTHS benchmark against numbers the benchmark's own code produced.

The published J-values of the maRTHS papers (Condori Uribe et al. 2023; Quiroz et al. 2024,
the RoDeAC controller) are in their tables, which are not available here (docs/marths.md
lists where they were looked for).  What is public is the RoDeAC repository
(github.com/FermandoisLab/maRTHS-bmk-RoDeAC, MIT), and in it a number the benchmark's
MATLAB/Simulink model computed: ``Support_files/Initial_parameters.mat``, the mean of the
least-squares fits of ``Offline_calibration.m`` over 99 uncompensated experiments
(El Centro, Kobe and Morgan Hill at 0.2, 0.4 and 0.6; the nominal plant and 10 uncertain
plants each).  Per experiment and actuator the fit is

    target(k) = theta . [xm(k), xm(k-1), xm(k-2), xm(k-3)]     (strokes in metres)

over the uncompensated run of ``Model_Calibration.slx``: the numerical substructure alone
(no feedback force), target strokes through the coupler, command = target, the control
plant, sensor noise on the measured strokes.  theta is an inverse model of the plant and
its coefficients depend on everything in that chain: the plant's gains, poles and zeros
and their uncertainty, the sensor noise (it shrinks the coefficients: from about 1.3 at
Morgan Hill x 0.2 to 9.9 at El Centro x 0.6 for the nominal plant), the structure, the
coupler and the three records.  Reproducing the published mean with the port checks that
chain against the benchmark's own numbers; ``P0 = (Gamma^T Gamma)^-1`` checks the stroke
amplitudes and record lengths (it scales with 1 / (samples x stroke power)).

The same procedure is run here with the port's pieces (:mod:`rths_bench.marths`) and each
coefficient compared with the published one at the issue's 15 % tolerance.  The uncertain
plants are drawn from ``--seed`` (the benchmark shuffles MATLAB's generator), so the mean
differs by sampling; the spread over plants at one record and scale is ~2 % of a
coefficient, ~0.2 % on the mean of 90.
"""

import json
import math
import os
import sys
import time

import numpy as np

from rths_bench.marths import (
    Newmark,
    PlantBatch,
    draw_plant_params,
    load_config,
    numerical_matrices,
    plant_params,
    rig_coupler,
)
from rths_bench.rths_benchmark import DATA_ENV, ground_acceleration

#: Records of ``Offline_calibration.m`` (EQ_sw 1, 2, 3), names of :data:`rths_benchmark.RECORDS`.
RECORDS = ('elcentro', 'kobe', 'morganhill')
#: Taps of the RoDeAC fit (the measured stroke now and 3 samples back).
TAPS = 4
#: The issue's port-fidelity tolerance [%].
TOLERANCE_PCT = 15.0


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def open_loop_targets(cfg: dict, ag) -> np.ndarray:
    """Target strokes [mm] (samples x 2) of the numerical substructure under ``ag``, no feedback.

    ``Model_Calibration.slx``: the substructure's interface (x, theta) through the coupler's
    exact kinematics, with no force from the physical frame.
    """
    fs = cfg['fs_hz']['value']
    num = Newmark(*numerical_matrices(cfg), 1.0 / fs, 1)
    coupler = rig_coupler(cfg)
    dofs = {k: v - 1 for k, v in cfg['reference']['dofs'].items()}
    n = len(ag)
    x = np.empty(n)
    th = np.empty(n)
    for k in range(n):
        u = num.step(ag[k])[0]
        x[k], th[k] = u[dofs['x']], -u[dofs['theta']]
    return 1000.0 * coupler.strokes(x, th).T


def measured_strokes(cfg: dict, target_mm, plants: list, rng) -> np.ndarray:
    """Measured strokes [mm] (samples x runs x 2) of ``plants`` commanded with their targets.

    ``target_mm`` is (samples x runs x 2): run i drives plant i with command = target
    (uncompensated), the measurement of sample k answering the commands up to k - 1.
    """
    fs = cfg['fs_hz']['value']
    plant = PlantBatch(plants, 1.0 / fs, math.sqrt(cfg['channels']['noise_power'] * fs), rng)
    n, batch = target_mm.shape[:2]
    out = np.empty((n, batch, 2))
    u_prev = np.zeros((batch, 2))
    for k in range(n):
        out[k] = plant.output(u_prev)
        plant.advance(target_mm[k])
        u_prev = target_mm[k]
    return out


def calibration_fit(target_mm, measured_mm, taps: int = TAPS):
    """``(theta, P0)`` of the RoDeAC fit of one actuator (``Offline_calibration.m``).

    Rows ``[xm(k), xm(k-1), ..., xm(k-taps+1)]`` and right-hand side ``target(k)``, for
    k = taps - 1 ... end, all in metres; ``theta`` by least squares, ``P0`` the inverse
    of the normal matrix (the RLS's initial inverse correlation).
    """
    xm = np.asarray(measured_mm, float) * 1e-3
    t = np.asarray(target_mm, float) * 1e-3
    n = xm.size
    if n <= taps or t.size != n:
        raise ValueError(f'calibration fit: need {taps + 1}+ samples of equal length, got '
                         f'{t.size} and {n}')
    gamma = np.column_stack([xm[taps - 1 - j:n - j] for j in range(taps)])
    p0 = np.linalg.inv(gamma.T @ gamma)
    return p0 @ gamma.T @ t[taps - 1:], p0


def run_calibration(cfg: dict = None, records=RECORDS, scales=None, n_draws: int = None,
                    seed: int = 2024, data_dir: str = None, log=_log) -> dict:
    """Run the 99 calibration experiments (or a subset); return every fit and the means.

    Returns ``{'experiments': [{record, scale, plant, theta: [[4], [4]], p0_diag}],
    'theta_mean': [[4], [4]], 'p0_mean': [[[4 x 4]], ...]}``.
    """
    cfg = cfg or load_config()
    pub = cfg['rodeac_calibration']
    scales = list(pub['scales'] if scales is None else scales)
    n_draws = pub['uncertain_per_case'] if n_draws is None else n_draws
    fs = cfg['fs_hz']['value']
    rng = np.random.default_rng(seed)
    experiments, thetas, p0s = [], [[], []], [[], []]
    for record in records:
        _, ag = ground_acceleration(record, fs, 1.0, data_dir, None)
        t0 = time.perf_counter()
        unit = open_loop_targets(cfg, ag)                      # linear: scale afterwards
        plants, tags, targets = [], [], []
        for scale in scales:
            for j in range(n_draws + 1):
                plants.append(plant_params(cfg) if j == 0 else draw_plant_params(cfg, rng))
                tags.append((scale, 'nominal' if j == 0 else f'uncertain {j}'))
                targets.append(scale * unit)
        meas = measured_strokes(cfg, np.stack(targets, axis=1), plants, rng)
        for r, (scale, tag) in enumerate(tags):
            row = {'record': record, 'scale': scale, 'plant': tag, 'theta': [], 'p0_diag': []}
            for i in range(2):
                theta, p0 = calibration_fit(targets[r][:, i], meas[:, r, i])
                thetas[i].append(theta)
                p0s[i].append(p0)
                row['theta'].append([float(v) for v in theta])
                row['p0_diag'].append([float(v) for v in np.diag(p0)])
            experiments.append(row)
        log(f'  {record}: {len(ag)} samples, {len(tags)} experiments, '
            f'{time.perf_counter() - t0:.1f} s')
    return {'experiments': experiments,
            'theta_mean': [np.mean(thetas[i], axis=0).tolist() for i in range(2)],
            'p0_mean': [np.mean(p0s[i], axis=0).tolist() for i in range(2)]}


def compare(measured: dict, cfg: dict = None, tolerance_pct: float = TOLERANCE_PCT) -> list:
    """Rows ``{name, published, measured, rel_diff_pct, pass, source}`` per coefficient.

    theta (4 per actuator) and the diagonal of P0 (4 per actuator) of the means.
    """
    cfg = cfg or load_config()
    pub = cfg['rodeac_calibration']
    source = (f"{cfg['_source'].split(', folder')[0]}: maRTHS-bmk-RoDeAC/"
              f"{pub['file'].split(' (')[0]}")
    rows = []
    for i in range(2):
        pairs = [(f'theta_{i + 1}[{j}]', pub['theta0'][i][j], measured['theta_mean'][i][j])
                 for j in range(TAPS)]
        pairs += [(f'P0_{i + 1}[{j},{j}]', pub['P0'][i][j][j], measured['p0_mean'][i][j][j])
                  for j in range(TAPS)]
        for name, p, m in pairs:
            rel = 100.0 * (m - p) / abs(p)
            rows.append({'name': name, 'published': p, 'measured': m,
                         'rel_diff_pct': round(rel, 3), 'pass': abs(rel) <= tolerance_pct,
                         'source': source})
    return rows


def run_fidelity(seed: int = 2024, n_draws: int = None, data_dir: str = None,
                 log=_log) -> dict:
    """Run the whole check (calibration experiments, comparison); return the summary."""
    t0, c0 = time.perf_counter(), time.process_time()
    cfg = load_config()
    pub = cfg['rodeac_calibration']
    n_draws = pub['uncertain_per_case'] if n_draws is None else n_draws
    log(f'maRTHS port fidelity: the RoDeAC offline calibration ({len(RECORDS)} records x '
        f"{len(pub['scales'])} scales x (nominal + {n_draws} uncertain plants))")
    measured = run_calibration(cfg, seed=seed, n_draws=n_draws, data_dir=data_dir, log=log)
    rows = compare(measured, cfg)
    worst = max(abs(r['rel_diff_pct']) for r in rows)
    # lazy: the machine's description lives beside the real-time loop's benchmark
    from rths_bench.bench_loop import machine_info
    return {
        'date': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
        'machine': machine_info(),
        'check': 'RoDeAC offline calibration (Offline_calibration.m) reproduced by the port',
        'tolerance_pct': TOLERANCE_PCT,
        'comparison': rows,
        'all_within_tolerance': all(r['pass'] for r in rows),
        'max_abs_rel_diff_pct': worst,
        'published_j_values': 'not available here (docs/marths.md: where they were looked for)',
        'settings': {'records': list(RECORDS), 'scales': pub['scales'],
                     'uncertain_per_case': n_draws,
                     'seed': seed, 'fs_hz': cfg['fs_hz']['value'],
                     'total_s': round(time.perf_counter() - t0, 2),
                     'cpu_s': round(time.process_time() - c0, 2),
                     'load_average_1min': round(os.getloadavg()[0], 2)},
        'experiments': measured['experiments'],
    }


def table_text(summary: dict) -> str:
    """PASS/MISS lines per coefficient."""
    lines = [f"{'coefficient':14s} {'published':>12s} {'port':>12s} {'diff %':>8s}"]
    for r in summary['comparison']:
        verdict = 'PASS' if r['pass'] else 'MISS'
        lines.append(f"{r['name']:14s} {r['published']:12.5g} {r['measured']:12.5g} "
                     f"{r['rel_diff_pct']:8.2f}  {verdict}")
    lines.append(f"largest |difference| {summary['max_abs_rel_diff_pct']:.2f} % (tolerance "
                 f"{summary['tolerance_pct']:g} %): "
                 f"{'PASS' if summary['all_within_tolerance'] else 'MISS'}")
    return '\n'.join(lines)


def _cmd(args) -> int:
    summary = run_fidelity(args.seed, args.draws, args.data_dir,
                           log=(lambda m: None) if args.quiet else _log)
    print(table_text(summary))
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, 'summary.json')
    with open(path, 'w') as fh:
        json.dump(summary, fh, indent=1, allow_nan=False)
        fh.write('\n')
    print(f'wrote {path}')
    st = summary['settings']
    print(f"total {st['total_s']} s (CPU {st['cpu_s']} s), load average "
          f"{st['load_average_1min']}")
    return 0 if summary['all_within_tolerance'] else 1


def register(commands, benches):
    """Add ``rths bench marths-fidelity``."""
    p = benches.add_parser(
        'marths-fidelity',
        help="the maRTHS port against the benchmark code's own numbers (RoDeAC calibration)",
        description='Port fidelity of the maRTHS benchmark: reruns the RoDeAC offline '
                    'calibration (Offline_calibration.m: El Centro, Kobe and Morgan Hill at '
                    '0.2, 0.4 and 0.6, the nominal plant and 10 uncertain plants each, '
                    'uncompensated, a 4-tap least-squares inverse model per actuator) with '
                    "the port and compares the mean coefficients and P0 with the ones the "
                    "benchmark's MATLAB model computed (Initial_parameters.mat of "
                    'github.com/FermandoisLab/maRTHS-bmk-RoDeAC): PASS/MISS per coefficient '
                    'at 15 %; exit 1 on a MISS. Writes DIR/summary.json (comparison: '
                    'published, measured, rel_diff_pct, source). The three records are the '
                    f'benchmark\'s MAT files, read from ${DATA_ENV} (or --data-dir).')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--data-dir', default=None,
                   help=f'directory of the three records (default ${DATA_ENV})')
    p.add_argument('--draws', type=int, default=None,
                   help='uncertain plants per record and scale (default 10, as the benchmark)')
    p.add_argument('--seed', type=int, default=2024, help='seed of the draws and the noise')
    p.add_argument('--quiet', action='store_true', help='no progress lines on stderr')
    p.set_defaults(func=_cmd)
