"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

* ``rths simulate``: whole building + DTMs numerically (seed 6.3.4), tables 6-8 metrics.
* ``rths study building-frequency`` (seed 7.1) and ``rths study dtm-tuning`` (seed 7.2).
* ``rths bench numerical``: step times of the integrators and the dtm-tuning run time.
"""

import functools
import json
import os
import time

from rths_common.files import atomic_open, save_figure
from rths_common.params import add_renamed_option

from .dtm import SEED_CONFIGURATION, STUDY_CONFIGURATIONS, TABLE4, dtm_configuration

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def _progress(label):
    """Return a ``(i, n)`` callback drawing a progress line (rths_common.progress)."""
    from rths_common.progress import Progress

    bar = Progress(0, label)

    def report(i, n):
        bar.update(i, n)
        if i >= n:
            bar.close()
    return report


def _write_json(path, data):
    """Write JSON atomically (temp file in the same directory, then rename)."""
    with atomic_open(path) as fh:
        json.dump(data, fh, indent=2, default=_jsonable)


def _jsonable(obj):
    import numpy as np
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f'cannot write {type(obj).__name__} to JSON')


def _save_fig(fig, path):
    save_figure(fig, path, dpi=120)


def _building(name, mass=None):
    from .building import BUILDING_MASS_KG, building_16dof, building_240dof
    from .model import load_model_yaml
    if name in ('building2story', '16'):
        return building_16dof(mass or BUILDING_MASS_KG)
    if name == 'building2story-240':
        return building_240dof(mass or BUILDING_MASS_KG)
    if not os.path.exists(name):
        raise ValueError(f'--building {name!r}: use building2story, building2story-240 or an '
                         'existing model YAML path')
    return load_model_yaml(name)


def cmd_simulate(args):
    """Run ``rths simulate``."""
    import numpy as np

    from .ground_motion import baseline_correct, ground_motion, peak_g
    from .reference import INCH, simulate_reference, simulate_uncontrolled
    model = _building(args.building)
    fs = args.fs_hz
    ag = ground_motion(args.record, fs, args.scale, args.duration_s or None, rng=args.seed)
    ag, _, _ = baseline_correct(ag, 1 / fs)
    print(f'model {model.name} ({model.n} DOF), record {args.record} x {args.scale} '
          f'(peak {peak_g(ag):.4f} g, {ag.size / fs:.1f} s at {fs:g} Hz)', flush=True)
    unc = simulate_uncontrolled(model, ag, 1 / fs, args.integrator)
    rows = {'uncontrolled': unc}
    dampers = list(STUDY_CONFIGURATIONS) if args.specimen == 'all' else (
        [] if args.specimen == 'none' else [args.specimen])
    for d in dampers:
        rows[d] = simulate_reference(model, ag, 1 / fs, d, args.n_dtm, integrator=args.integrator,
                                     uncontrolled=unc)
    print(f'{"model":14s} {"max (in)":>9s} {"red. %":>7s} {"RMS (in)":>9s} {"red. %":>7s}')
    for name, res in rows.items():
        m = res['metrics']
        print(f'{name:14s} {m["max_disp_m"] / INCH:9.4f} {m.get("max_reduction_pct", 0):7.1f} '
              f'{m["rms_disp_m"] / INCH:9.4f} {m.get("rms_reduction_pct", 0):7.1f}')
    os.makedirs(args.out, exist_ok=True)
    data = {'model': model.name, 'record': args.record, 'scale': args.scale, 'fs_hz': fs,
            'n_dtm': args.n_dtm, 'peak_ground_g': peak_g(ag),
            'results': {k: v['metrics'] for k, v in rows.items()}}
    _write_json(os.path.join(args.out, 'simulate.json'), data)
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(rows), 1, sharex=True, figsize=(9, 2.2 * len(rows) + 1))
    axes = np.atleast_1d(axes)
    for ax, (name, res) in zip(axes, rows.items(), strict=True):
        ax.plot(res['time'], res['disp'] / INCH, lw=0.8)
        ax.set_ylabel('2nd floor (in)')
        ax.set_title(name, fontsize=9)
    axes[-1].set_xlabel('time (s)')
    fig.tight_layout()
    _save_fig(fig, os.path.join(args.out, 'simulate.png'))
    print(f'wrote {args.out}/simulate.json and simulate.png')
    return 0


def _surface_plot(path, x, y, surfaces, xlabel, ylabel, title):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    from .studies import CRITERIA
    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for ax, c in zip(axes.ravel(), CRITERIA, strict=True):
        cs = ax.contourf(x, y, np.asarray(surfaces[c]).T, 30)
        fig.colorbar(cs, ax=ax)
        ax.set_title(c.replace('_', ' ') + (' (m)' if 'disp' in c else ' (m/s^2)'), fontsize=9)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
    fig.suptitle(title)
    fig.tight_layout()
    _save_fig(fig, path)


def cmd_study_building_frequency(args, surfaces=None):
    """Run ``rths study building-frequency``.

    ``surfaces(damper, f1_hz, mass_ratios)``: the criteria computed elsewhere (the study
    runner, which ``rths_study`` plugs in here); default: this process.
    """
    import numpy as np

    from .ground_motion import baseline_correct, ground_motion
    from .studies import CRITERIA, building_frequency_study, den_hartog, warburton_ground
    model = _building(args.building)
    fs = args.fs_hz
    ag, _, _ = baseline_correct(ground_motion(args.record, fs, args.scale, None), 1 / fs)
    f1 = np.linspace(args.f1_min, args.f1_max, args.n_freq)
    mu = np.linspace(0.0, args.mu_max, args.n_ratio)
    os.makedirs(args.out, exist_ok=True)
    result = {}
    for damper in args.dampers:
        grid = None if surfaces is None else functools.partial(surfaces, damper)
        res = building_frequency_study(model, ag, 1 / fs, f1, mu, damper,
                                       progress=_progress(f'building-frequency {damper}'),
                                       surfaces=grid)
        result[damper] = {c: res[c] for c in CRITERIA}
        best = {}
        for c in CRITERIA:
            i = int(np.argmin(res[c][:, -1]))
            best[c] = float(f1[i])
        result[damper]['f1_of_minimum_at_max_ratio_hz'] = best
        print(f'{damper}: f1 minimising each criterion at mass ratio {mu[-1]:.3f}: {best}')
        # Classical optima for this DTM (its f_n and zeta are fixed, the building is tuned):
        # the building frequency f1 = f_n / f_ratio, and the damping the DTM would need.
        dtm = dtm_configuration(damper)
        classic = {}
        for name, formula in (('den_hartog', den_hartog), ('warburton_ground', warburton_ground)):
            f_ratio, zeta_opt = formula(float(mu[-1]))
            classic[name] = {'f1_hz': dtm.f_n / f_ratio, 'zeta_opt': zeta_opt}
        classic['dtm_f_n_hz'], classic['dtm_zeta'] = dtm.f_n, dtm.zeta
        result[damper]['classical_optima_at_max_ratio'] = classic
        print(f"  Den Hartog: f1 = {classic['den_hartog']['f1_hz']:.2f} Hz with zeta_opt "
              f"{100 * classic['den_hartog']['zeta_opt']:.1f} %; Warburton (ground): f1 = "
              f"{classic['warburton_ground']['f1_hz']:.2f} Hz, zeta_opt "
              f"{100 * classic['warburton_ground']['zeta_opt']:.1f} %; this DTM: f_n "
              f"{dtm.f_n:.2f} Hz, zeta {100 * dtm.zeta:.1f} %")
        _surface_plot(os.path.join(args.out, f'building_frequency_{damper}.png'), f1, mu, res,
                      'building f1 (Hz)', 'mass ratio', f'seed 7.1, DTM {damper}')
    data = {'record': args.record, 'scale': args.scale, 'f1_hz': f1, 'mass_ratios': mu,
            'results': result}
    _write_json(os.path.join(args.out, 'building_frequency.json'), data)
    print(f'wrote {args.out}/building_frequency.json and PNGs')
    return 0


def run_dtm_tuning(n_fn=100, n_zeta=30, duration_s=60.0, fs_hz=256.0, seed=0, mass_ratio=0.01,
                   f1_hz=2.81, progress=None, surfaces=None):
    """Seed 7.2 study on the 16-DOF building with BLWN 0-10 Hz, 1 g peak; return the result.

    ``surfaces(fn_hz, zetas)``: the criteria computed elsewhere (:func:`dtm_tuning_study`).
    """
    import numpy as np

    from .building import building_16dof
    from .ground_motion import G
    from .signals import blwn
    from .studies import dtm_tuning_study
    ag = blwn(duration_s, fs_hz, 10.0, 1.0 * G, rng=seed)
    return dtm_tuning_study(building_16dof(), ag, 1 / fs_hz, np.linspace(0.1, 10.0, n_fn),
                            np.linspace(0.005, 0.15, n_zeta), mass_ratio, f1_hz, progress,
                            surfaces)


def cmd_study_model_reduction(args):
    """``rths study model-reduction``: seed figure 33, 16-DOF vs 240-DOF 2nd-floor response.

    Three models under the same record: the condensed 16-DOF building, the 240-DOF frame
    with the rigid diaphragms the condensation assumes (the figure 33 comparison) and the
    bare 240-DOF frame (``diaphragms=False``, floors flexible in plane).
    """
    import numpy as np

    from . import building as bld
    from .ground_motion import baseline_correct, ground_motion
    from .reference import integrate_model, relative_rms_error
    dt = 1.0 / args.fs_hz
    ag, _, _ = baseline_correct(ground_motion(args.record, args.fs_hz, args.scale,
                                              args.duration_s), dt)
    models = {'16dof': bld.building_16dof(), '240dof': bld.building_240dof(),
              '240dof_bare': bld.building_240dof(diaphragms=False)}
    resp = {}
    report = _progress('model-reduction')
    for k, (key, model) in enumerate(models.items()):
        report(k, len(models))
        d, _ = integrate_model(model, ag, dt)
        # 240 DOF: mean ux of the 20 2nd-floor nodes (with diaphragms they all move alike)
        resp[key] = d[:, bld.IX2] if key == '16dof' else d[:, bld.floor2_x_dofs_240()].mean(1)
    report(len(models), len(models))
    data = {'record': args.record, 'scale': args.scale, 'fs_hz': args.fs_hz,
            'duration_s': args.duration_s, 'integrator': 'cr',
            'diaphragm_penalty': bld.DIAPHRAGM_PENALTY}
    for key, model in models.items():
        f1, f2 = (float(f) for f in model.dominant_frequencies(2)[0])
        u = resp[key]
        data.update({f'f1_{key}_hz': f1, f'f2_{key}_hz': f2,
                     f'max_disp_{key}_m': float(np.max(np.abs(u))),
                     f'rms_disp_{key}_m': float(np.sqrt(np.mean(u ** 2)))})
    data['rel_rms_diff_pct'] = relative_rms_error(resp['240dof'], resp['16dof'])
    data['rel_rms_diff_bare_pct'] = relative_rms_error(resp['240dof_bare'], resp['16dof'])
    os.makedirs(args.out, exist_ok=True)
    _write_json(os.path.join(args.out, 'model_reduction.json'), data)
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    t = np.arange(ag.size) * dt
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t, resp['240dof_bare'] * 1e3, color='0.6', lw=0.8,
            label='240 DOF, bare frame (no diaphragm), mean of 2nd-floor nodes')
    ax.plot(t, resp['240dof'] * 1e3, label='240 DOF with rigid diaphragms (penalty)')
    ax.plot(t, resp['16dof'] * 1e3, '--', label='16 DOF (rigid diaphragms, condensed)')
    ax.set_xlabel('time [s]')
    ax.set_ylabel('2nd-floor displacement [mm]')
    ax.set_title(f'{args.record} x {args.scale:g}: relative RMS difference 16 vs 240 DOF '
                 f"{data['rel_rms_diff_pct']:.3f} % (bare frame "
                 f"{data['rel_rms_diff_bare_pct']:.1f} %)")
    ax.legend()
    fig.tight_layout()
    _save_fig(fig, os.path.join(args.out, 'model_reduction.png'))
    plt.close(fig)
    for key, label in (('16dof', '16 DOF'), ('240dof', '240 DOF, diaphragms'),
                       ('240dof_bare', '240 DOF, bare frame')):
        print(f"{label:20s}: f1 {data[f'f1_{key}_hz']:.4f} Hz, f2 {data[f'f2_{key}_hz']:.4f} Hz; "
              f"2nd floor peak {data[f'max_disp_{key}_m'] * 1e3:.4f} mm, "
              f"RMS {data[f'rms_disp_{key}_m'] * 1e3:.4f} mm")
    print(f"relative RMS difference vs 16 DOF: 240 DOF with diaphragms "
          f"{data['rel_rms_diff_pct']:.3f} %, bare frame {data['rel_rms_diff_bare_pct']:.2f} %")
    print(f'wrote {args.out}/model_reduction.json and model_reduction.png')
    return 0


def cmd_study_dtm_tuning(args, surfaces=None):
    """Run ``rths study dtm-tuning``; ``surfaces``: see :func:`run_dtm_tuning`."""
    from .studies import CRITERIA
    if args.n_fn < 2 or args.n_zeta < 2:
        raise ValueError('--n-fn and --n-zeta must be >= 2')
    res = run_dtm_tuning(args.n_fn, args.n_zeta, args.duration_s, args.fs_hz, args.seed,
                         args.mass_ratio, args.f1_hz, _progress('dtm-tuning'), surfaces)
    seed_optima = {'max_disp': (1.7, 0.06), 'max_accel': (1.8, 0.02), 'rms_disp': (1.8, 0.04),
                   'rms_accel': (1.8, 0.04)}
    print(f'building f1 = {args.f1_hz} Hz, mass ratio {args.mass_ratio} '
          f'(mu on the first-mode mass: {res["mu_modal"]:.4f})')
    for c in CRITERIA:
        o = res['optima'][c]
        s = seed_optima[c]
        print(f'{c:10s} optimum f_n = {o["fn_hz"]:.2f} Hz, zeta = {100 * o["zeta"]:.1f} % '
              f'(seed: {s[0]} Hz, {100 * s[1]:.0f} %)')
    dh, wb = res['den_hartog'], res['warburton_ground']
    print(f'Den Hartog: f_n = {dh["fn_hz"]:.2f} Hz, zeta = {100 * dh["zeta"]:.1f} %; '
          f'Warburton (ground accel.): f_n = {wb["fn_hz"]:.2f} Hz, '
          f'zeta = {100 * wb["zeta"]:.1f} %')
    os.makedirs(args.out, exist_ok=True)
    res['seed_optima'] = {c: {'fn_hz': v[0], 'zeta': v[1]} for c, v in seed_optima.items()}
    _write_json(os.path.join(args.out, 'dtm_tuning.json'), res)
    _surface_plot(os.path.join(args.out, 'dtm_tuning.png'), res['fn_hz'], 100 * res['zetas'],
                  res, 'DTM f_n (Hz)', 'DTM zeta (%)', 'seed 7.2: building 2.81 Hz, mu = 1 %')
    print(f'wrote {args.out}/dtm_tuning.json and dtm_tuning.png')
    return 0


def _best_step_us(step, repeats=5, n=2000):
    """Best over ``repeats`` runs of the mean time [us] of ``n`` calls of ``step()``."""
    best = float('inf')
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            step()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def _time_steps(model, name, dt):
    """Time [us] of one integrator step, ``predict`` + ``correct``."""
    import numpy as np

    from .integrators import make_integrator
    integ = make_integrator(name, model.M, model.C, model.K, dt)
    p = np.zeros(model.n)
    r = np.zeros(model.n)

    def step():
        integ.predict(p)
        integ.correct(p, r)
    return _best_step_us(step)


def _time_advance(model, name, dt, repeats=5, n=2000):
    """Time [us] of one ``NumericalSubstructure.advance`` (what the node pays per step)."""
    import numpy as np

    from .substructure import NumericalSubstructure
    sub = NumericalSubstructure(model, np.zeros(repeats * n + 2), dt, integrator=name)
    force = np.zeros(sub.n_interface)
    sub.advance(force)          # step 0 sets the integrator state
    return _best_step_us(lambda: sub.advance(force), repeats, n)


def _advance_p50_us(sub, specimen):
    """Median [us] of the per-step ``advance`` time over a whole coupled run (and the history)."""
    import numpy as np
    times = np.zeros(sub.n_steps)
    command = sub.first_displacement()
    k = 0
    while not sub.done():
        force = specimen(command)
        t0 = time.perf_counter_ns()
        command = sub.advance(force)
        times[k] = time.perf_counter_ns() - t0
        k += 1
    return float(np.median(times) * 1e-3), sub.history()


def _backend_comparison(backend, record, scale, duration_s, fs_hz):
    """Backend ``backend`` vs builtin on the 16-DOF building with the valve #4 DTM specimen."""
    from .reference import DTMSpecimen, relative_rms_error
    from .substructure import make_substructure
    base = {'model': 'building2story', 'record': record, 'scale': scale,
            'duration_s': duration_s, 'fs_hz': fs_hz}
    keys = ('output_disp', 'measured_force', 'command')
    out = {'record': record, 'scale': scale, 'duration_s': duration_s, 'compared': list(keys)}
    runs = {}
    for label, be, integ in (('builtin_cd', 'builtin', 'central_difference'),
                             ('builtin_cr', 'builtin', 'cr'),
                             (backend, backend, 'central_difference')):
        sub = make_substructure(dict(base, backend=be, integrator=integ))
        p50, runs[label] = _advance_p50_us(sub, DTMSpecimen(SEED_CONFIGURATION, sub.dt))
        out[f'step_us_p50_{label}'] = p50

    def diff(a, b):
        return max(relative_rms_error(runs[a][k], runs[b][k]) / 100 for k in keys)
    out['max_rel_diff_vs_builtin'] = diff(backend, 'builtin_cd')
    out['max_rel_diff_vs_builtin_cr'] = diff(backend, 'builtin_cr')
    out['step_us_p50'] = out[f'step_us_p50_{backend}']
    return out


def cmd_bench_numerical(args):
    """Run ``rths bench numerical``."""
    from .building import building_16dof, building_240dof, x_frequencies
    load_start = list(os.getloadavg())
    if args.backend != 'builtin':
        from .opensees_backend import import_opensees
        import_opensees()   # OSError naming the fix, before minutes of other work
    b16 = building_16dof()
    b240 = building_240dof()
    f1, f2 = x_frequencies(b16)
    dt = 1.0 / args.fs_hz
    from rths_common.progress import Progress

    steps = {}
    bar = Progress(3, 'integrator timings')
    for name in ('cr', 'kr_alpha', 'newmark'):
        steps[name] = {'16': _time_steps(b16, name, dt), '240': _time_steps(b240, name, dt),
                       'advance_16': _time_advance(b16, name, dt),
                       'advance_240': _time_advance(b240, name, dt)}
        with bar.hidden():
            print(f'{name:9s} step: 16 DOF {steps[name]["16"]:.1f} us, '
                  f'240 DOF {steps[name]["240"]:.1f} us; substructure advance (the node\'s '
                  f'step): {steps[name]["advance_16"]:.1f} / {steps[name]["advance_240"]:.1f} us',
                  flush=True)
        bar.advance()
    bar.close()
    t0 = time.perf_counter()
    res = run_dtm_tuning(n_fn=args.n_fn, n_zeta=args.n_zeta, progress=_progress('dtm-tuning'))
    tuning_s = time.perf_counter() - t0
    f1_240 = building_240dof().dominant_frequencies(2)[0]
    data = {'f1_hz': f1, 'f2_hz': f2, 'seed_f1_hz': 2.81, 'seed_f2_hz': 7.77,
            'f1_240dof_hz': float(f1_240[0]), 'f2_240dof_hz': float(f1_240[1]),
            'step_us_16dof': steps['cr']['16'], 'step_us_240dof': steps['cr']['240'],
            'step_us_by_integrator': steps, 'dtm_tuning_s': tuning_s,
            'dtm_tuning_grid': [args.n_fn, args.n_zeta], 'dtm_tuning_optima': res['optima'],
            'fs_hz': args.fs_hz, 'integrator_for_step_fields': 'cr'}
    print(f'f1_hz {f1:.3f} (seed 2.81), f2_hz {f2:.3f} (seed 7.77)')
    print(f'step_us_16dof {data["step_us_16dof"]:.1f} (target <= 20), step_us_240dof '
          f'{data["step_us_240dof"]:.1f} (target <= 100)')
    print(f'dtm_tuning_s {tuning_s:.2f} for {args.n_fn} x {args.n_zeta} grid (target <= 60)')
    data['backend'] = args.backend
    data['load_average_start'] = load_start
    if args.backend != 'builtin':
        span = f'{args.duration_s:g} s' if args.duration_s else 'whole record'
        print(f'{args.backend} vs builtin: 16-DOF building + valve #4 DTM, '
              f'{args.record} x {args.scale}, {span}', flush=True)
        cmp = _backend_comparison(args.backend, args.record, args.scale, args.duration_s,
                                  args.fs_hz)
        data.update(max_rel_diff_vs_builtin=cmp['max_rel_diff_vs_builtin'],
                    step_us_p50=cmp['step_us_p50'], backend_comparison=cmp)
        print(f'max_rel_diff_vs_builtin {cmp["max_rel_diff_vs_builtin"]:.2e} (central difference '
              f'in both; target <= 1e-3), vs builtin cr {cmp["max_rel_diff_vs_builtin_cr"]:.2e}')
        print(f'step_us_p50 {cmp["step_us_p50"]:.1f} (advance, 16 DOF; target <= 100); builtin '
              f'central difference {cmp["step_us_p50_builtin_cd"]:.1f}, cr '
              f'{cmp["step_us_p50_builtin_cr"]:.1f}')
    data['load_average_end'] = list(os.getloadavg())
    print(f'load average {load_start[0]:.1f} at the start, {data["load_average_end"][0]:.1f} at '
          'the end (timings are noisy on a shared machine)')
    _write_json(args.out, data)
    print(f'wrote {args.out}')
    return 0


def cmd_fit_mr(args):
    """Run ``rths fit-mr``: fit the Spencer et al. (1997) model to real sinusoid tests."""
    import numpy as np

    from . import mr_fit
    from .mr_damper import SPENCER_1997
    tests = mr_fit.load_tests(mr_fit.data_dir(args.data))
    print(f'{len(tests)} sinusoid tests, currents '
          f'{sorted({t["current_a"] for t in tests})} A; fitting (about a minute)', flush=True)
    from rths_common.progress import Progress

    t0 = time.perf_counter()
    with Progress(0, 'fit-mr', 'model evaluations') as bar:
        best, errors, nfev = mr_fit.fit(tests, max_nfev=args.max_nfev, progress=bar.report)
    names = [t['name'] for t in tests]
    worst = names[int(np.argmax(errors))]
    print(f'fitted in {time.perf_counter() - t0:.1f} s ({nfev} evaluations): relative RMS '
          f'force error mean {errors.mean():.1f} %, worst {errors.max():.1f} % ({worst})')
    paper = mr_fit.paper_errors(tests)
    print('the paper\'s parameters (best constant voltage per current): ' + ', '.join(
        f'{c} A -> {v["best_voltage_v"]:.2f} V, mean '
        f'{np.mean(list(v["errors_pct"].values())):.1f} %' for c, v in paper.items()))
    fitted = best.as_dict()
    data = {
        'source': mr_fit.SOURCE,
        'model': 'Spencer, Dyke, Sain and Carlson (1997) phenomenological Bouc-Wen, current [A] '
                 'in place of voltage; n = 2 fixed; x0 and eta not identifiable (tared force, '
                 'constant current)',
        'fitted': {k: fitted[k] for k in mr_fit.FIT_KEYS} | {'n': fitted['n']},
        'paper_spencer_1997_per_volt': {k: getattr(SPENCER_1997, k)
                                        for k in mr_fit.FIT_KEYS} | {'n': SPENCER_1997.n},
        'units': 'SI: N, m, s; the *_b coefficients per A (fitted) or per V (paper)',
        'fit_errors_pct': dict(zip(names, errors.tolist(), strict=True)),
        'fit_error_mean_pct': float(errors.mean()), 'fit_error_max_pct': float(errors.max()),
        'paper_errors_at_best_voltage': paper,
        'paper_error_mean_pct': float(np.mean([e for v in paper.values()
                                               for e in v['errors_pct'].values()])),
        'evaluations': nfev,
        'comparable_fitted_0_to_1_A': mr_fit.comparable(best, 1.0),
        'comparable_paper_0_to_2_25_V': mr_fit.comparable(SPENCER_1997, 2.25),
    }
    _write_json(args.out, data)
    if args.plot:
        _mr_fit_plot(args.plot, tests, best)
        print(f'wrote {args.plot}')
    print(f'wrote {args.out}')
    return 0


def _mr_fit_plot(path, tests, params):
    """Force-stroke loops of the 1 A and 0 A tests: measured and fitted."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from .mr_fit import _inputs, simulate_tests
    inputs = _inputs(tests, 1000, 1.25)
    model, meas = simulate_tests(params, tests, inputs=inputs)
    x = inputs[0]
    pick = [i for i, t in enumerate(tests) if t['current_a'] in (0.0, 0.5, 1.0)]
    cols = 6
    rows = -(-len(pick) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3 * cols, 2.6 * rows), squeeze=False)
    for ax, i in zip(axes.ravel(), pick, strict=False):
        ax.plot(x[-1000:, i] * 1e3, meas[-1000:, i], 'k', lw=0.8, label='measured')
        ax.plot(x[-1000:, i] * 1e3, model[-1000:, i], 'r--', lw=0.8, label='fitted model')
        ax.set_title(tests[i]['name'], fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=7)
    fig.supxlabel('stroke [mm]')
    fig.supylabel('force [N]')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
    fm = commands.add_parser(
        'fit-mr', help='fit the MR-damper model (Spencer et al. 1997) to real sinusoid tests',
        description='Fit the phenomenological Bouc-Wen MR-damper model of Spencer, Dyke, Sain '
                    'and Carlson (1997) to the sinusoid tests (0-1 A) of '
                    'github.com/DanielMaurelE/vRTHS_AMBC_MRdamper (MIT; the Preprocesados/*.txt '
                    'files: t, x [mm], v [mm/s], F [N]); print the errors, compare with the '
                    "paper's parameters, write JSON (and a PNG of the loops).")
    fm.add_argument('--data', default=None,
                    help='directory of the test files (default: $RTHS_DATA_DIR/mr_damper; '
                         'RTHS_DATA_DIR unset: ../shared/data beside the repository)')
    fm.add_argument('--out', default='out/mr_fit.json', help='JSON results')
    fm.add_argument('--plot', default=None, help='PNG of measured and fitted loops')
    fm.add_argument('--max-nfev', type=int, default=200, help='least-squares evaluations')
    fm.set_defaults(func=cmd_fit_mr)
    sim = commands.add_parser(
        'simulate', help='whole building + DTMs numerically (seed 6.3.4), tables 6-8 metrics',
        description='Simulate the building uncontrolled and with 5 DTMs (all numerical, seed '
                    '6.3.4); print the 2nd-floor max and RMS displacement and their reduction '
                    '(tables 6-8 layout); write OUT/simulate.json and OUT/simulate.png.')
    sim.add_argument('--building', default='building2story',
                     help='building2story (16 DOF), building2story-240 or a model YAML path')
    sim.add_argument('--specimen', default='all', choices=['all', 'none'] + list(TABLE4),
                     help='the DTM specimen: a Table 4 configuration; all = valve4 and novalve')
    add_renamed_option(sim, '--damper', '--specimen')
    sim.add_argument('--record', default='kobe',
                     help='kobe, northridge, imperial_valley, blwn or a PEER .AT2 path')
    sim.add_argument('--scale', type=float, default=0.135, help='record scale factor')
    sim.add_argument('--fs-hz', type=float, default=1024.0, help='integration rate (Hz)')
    sim.add_argument('--duration-s', type=float, default=0.0, help='0 = whole record')
    sim.add_argument('--integrator', default='cr', choices=['cr', 'kr_alpha', 'newmark'])
    sim.add_argument('--n-dtm', type=int, default=5, help='number of DTMs (seed: 5)')
    sim.add_argument('--seed', type=int, default=0, help='random seed for blwn')
    sim.add_argument('--out', default='out/simulate', help='output directory')
    sim.set_defaults(func=cmd_simulate)

    study = commands.add_parser(
        'study', help='DTM parameter studies of seed chapter 7 (JSON + PNG surfaces)',
        description='Parameter studies of seed chapter 7, computed in the frequency domain.')
    studies = study.add_subparsers(dest='study', metavar='STUDY')
    studies.required = True
    bf = studies.add_parser(
        'building-frequency', help='seed 7.1: building f1 x mass ratio, four response surfaces',
        description='Seed 7.1: vary the building first frequency (stiffness scaling) and the '
                    'DTM/building mass ratio; write the four 2nd-floor criteria to '
                    'OUT/building_frequency.json and one PNG per damper.')
    bf.add_argument('--building', default='building2story')
    bf.add_argument('--record', default='imperial_valley', help='seed: El Centro')
    bf.add_argument('--scale', type=float, default=0.10)
    bf.add_argument('--fs-hz', type=float, default=200.0)
    bf.add_argument('--f1-min', type=float, default=1.96)
    bf.add_argument('--f1-max', type=float, default=5.0)
    bf.add_argument('--n-freq', type=int, default=40)
    bf.add_argument('--mu-max', type=float, default=0.05)
    bf.add_argument('--n-ratio', type=int, default=26)
    bf.add_argument('--dampers', nargs='+', default=list(STUDY_CONFIGURATIONS),
                    choices=list(TABLE4))
    bf.add_argument('--out', default='out/study')
    bf.set_defaults(func=cmd_study_building_frequency)
    dt_ = studies.add_parser(
        'dtm-tuning', help='seed 7.2: DTM f_n x zeta for a 2.81 Hz building, mu = 1 %%',
        description='Seed 7.2: DTM natural frequency 0.1-10 Hz x damping 0.5-15 %, mass 1 % of '
                    'the building, BLWN 0-10 Hz with 1 g peak; print the optima next to the '
                    "seed's and Den Hartog's; write OUT/dtm_tuning.json and dtm_tuning.png.")
    dt_.add_argument('--n-fn', type=int, default=199, help='grid points in f_n')
    dt_.add_argument('--n-zeta', type=int, default=30, help='grid points in zeta')
    dt_.add_argument('--duration-s', type=float, default=60.0, help='BLWN length (s)')
    dt_.add_argument('--fs-hz', type=float, default=256.0)
    dt_.add_argument('--seed', type=int, default=0)
    dt_.add_argument('--mass-ratio', type=float, default=0.01)
    dt_.add_argument('--f1-hz', type=float, default=2.81, help='building first frequency')
    dt_.add_argument('--out', default='out/study')
    dt_.set_defaults(func=cmd_study_dtm_tuning)

    mr = studies.add_parser(
        'model-reduction', help='seed figure 33: 2nd-floor response of the 16- and 240-DOF models',
        description='Seed 6.2 / figure 33: integrate the condensed 16-DOF building, the '
                    '240-DOF frame with rigid floor diaphragms and the bare 240-DOF frame '
                    'under the same ground motion; print their x frequencies, peak and RMS '
                    '2nd-floor displacements and relative RMS differences; write '
                    'OUT/model_reduction.json and model_reduction.png (the overlay).')
    mr.add_argument('--record', default='kobe', help='kobe, northridge, imperial_valley or AT2')
    mr.add_argument('--scale', type=float, default=0.135, help='record scale factor')
    mr.add_argument('--duration-s', type=float, default=12.0, help='seconds of record')
    mr.add_argument('--fs-hz', type=float, default=256.0, help='integration rate (Hz)')
    mr.add_argument('--out', default='out/study')
    mr.set_defaults(func=cmd_study_model_reduction)

    bn = benches.add_parser(
        'numerical', help='integrator step times (16/240 DOF) and dtm-tuning run time',
        description='Measure one CR/KR-alpha/Newmark step of the 16- and 240-DOF building, the '
                    'x frequencies, and the dtm-tuning study time; print and write JSON with '
                    'f1_hz, f2_hz, step_us_16dof, step_us_240dof, dtm_tuning_s, backend. '
                    'With --backend opensees also the RTHS of the 16-DOF building with the '
                    'valve #4 DTM on OpenSees and builtin (central difference in both): '
                    'max_rel_diff_vs_builtin and step_us_p50.')
    bn.add_argument('--out', default='out/bench_numerical.json')
    bn.add_argument('--fs-hz', type=float, default=1024.0)
    bn.add_argument('--n-fn', type=int, default=40)
    bn.add_argument('--n-zeta', type=int, default=30)
    bn.add_argument('--backend', default='builtin', choices=['builtin', 'opensees'],
                    help='opensees (OpenSeesPy, `make setup-opensees`): also run the 16-DOF '
                         'building with the valve #4 DTM on both backends and report backend, '
                         'max_rel_diff_vs_builtin and step_us_p50 (median advance time, us)')
    bn.add_argument('--record', default='kobe', help='record of the backend comparison')
    bn.add_argument('--scale', type=float, default=0.135, help='record scale factor')
    bn.add_argument('--duration-s', type=float, default=0.0,
                    help='seconds of record in the backend comparison; 0 = whole record')
    bn.set_defaults(func=cmd_bench_numerical)
