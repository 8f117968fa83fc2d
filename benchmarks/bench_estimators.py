"""Force estimators on synthetic records with known truth: time per sensor-sample against force error, and the
throughput of the recursive inverse on a 1024-sensor, 1 kHz stream.

Truth: the typical sensor (``models.sls.TYPICAL_SLS``, ``TYPICAL_AREA_M2``, default physics with the contact term),
Gaussian conductance noise. The linear model is calibrated the paper's way (mean conductance over 225–300 s of
370 s holds at 1.75, 3, 4, 5.25 N) on the same sensor. Run: ``python -m benchmarks.bench_estimators [--quick]``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from models.estimators import LinearEstimator, SLSEstimator
from models.linear import fit_linear_trials
from models.physics import DEFAULT_PHYSICS, conductance_from_strain
from models.sls import (
    TYPICAL_AREA_M2,
    TYPICAL_FORCES_N,
    TYPICAL_SLS,
    SLSParams,
    SLSTrend,
    _solve_contact_scalar,  # the per-step solve shared with the naive reference below
    conductance_from_force,
    force_from_conductance,
    force_from_conductance_trend,
    strain_from_force_trend,
)
from models.smoothing import smooth_tikhonov, tikhonov_lambda

NOISE_S = 1e-6  # ≈ 0.15 % of a typical loaded reading, ~3 counts of the 12-bit readout
NAIVE_MAX_SAMPLES = 10_000
REPEATS = 3


# ------------------------------------------------------------------------------------------------ scenarios


def _hold(quick: bool):
    t = np.arange(0.0, 370.0, 1 / 6)
    return t, np.where(t >= 5.0, 3.0, 0.0)


def _two_step(quick: bool):
    t = np.arange(0.0, 300.0, 1 / 6)
    return t, np.where(t >= 150.0, 4.0, np.where(t >= 10.0, 2.0, 0.0))


def _sine(quick: bool):
    t = np.arange(0.0, 60.0 if quick else 120.0, 1 / 30)
    return t, 3.0 + 1.5 * np.sin(2 * np.pi * 0.2 * t)


def _pulses(quick: bool):
    rng = np.random.default_rng(42)
    duration = 120.0 if quick else 300.0
    t = np.arange(0.0, duration, 1 / 30)
    force = np.zeros(t.size)
    start = 1.0
    while start < duration:
        length = float(np.exp(rng.uniform(np.log(0.1), np.log(10.0))))
        on = (t >= start) & (t < start + length)
        force[on] = rng.uniform(1.0, 5.0)
        start += length + rng.uniform(0.2, 3.0)
    return t, force


SCENARIOS: list[tuple[str, Callable, float, float]] = [
    # name, generator, smoother cut-off (Hz), conductance noise (S)
    ("hold 3 N, 370 s @ 6 Hz", _hold, 0.3, NOISE_S),
    ("2-step 2→4 N, 300 s @ 6 Hz", _two_step, 0.3, NOISE_S),
    ("sine 0.2 Hz ±1.5 N @ 30 Hz", _sine, 1.0, NOISE_S),
    ("sine 0.2 Hz ±1.5 N @ 30 Hz", _sine, 1.0, 10 * NOISE_S),
    ("pulses 0.1–10 s @ 30 Hz", _pulses, 3.0, NOISE_S),
]


# ------------------------------------------------------------------------------------------------ estimators


def _naive_superposition_inverse(t, cond, params: SLSParams, area_m2: float, phys) -> np.ndarray:
    """The paper's reverse superposition: at each sample the past increments are summed afresh (O(N²))."""
    e0, e1, tau = float(params.E0_Pa), float(params.E1_Pa), float(params.tau_s)  # one sensor
    k, r0, kc = phys.tunnelling_k, phys.R0_ohm, phys.K_contact_ohm_sqrtN
    sigma = np.zeros(t.size)
    force = np.zeros(t.size)
    f_prev = 0.0
    w = 1.0 / (e0 * area_m2)
    for i in range(t.size):
        if i:
            increments = np.diff(sigma[:i], prepend=0.0)
            compliance = 1.0 / e0 + (-np.expm1(-(t[i] - t[:i]) / tau)) / e1
            p = float(increments @ compliance) - sigma[i - 1] / e0
        else:
            p = 0.0
        c = cond[i]
        f = 0.0 if c <= 0.0 else _solve_contact_scalar(c, p, w, f_prev, k, r0, kc)[0]
        force[i] = f
        sigma[i] = f / area_m2
        f_prev = f if f > 0.0 else f_prev
    return force


def _calibrated_linear(window_s=(225.0, 300.0)):
    """Eq. 1 fitted to 370 s holds (loaded at 5 s) over ``window_s``: the paper's 225–300 s by default, or a window
    just after loading for an "instantaneous" calibration."""
    trials = []
    for f in TYPICAL_FORCES_N:
        t = np.arange(0.0, 370.0, 1 / 6)
        force = np.where(t >= 5.0, f, 0.0)
        trials.append(
            (t, force, conductance_from_force(t, force, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS))
        )
    return fit_linear_trials(trials, window_s=window_s).model


INSTANT_WINDOW_S = (5.0, 6.0)


def _timed(fn):
    """(result, seconds of this process's CPU time): on a shared machine wall time measures the neighbours too."""
    start = time.process_time()
    out = fn()
    return out, time.process_time() - start


def _errors(estimate, truth, mask):
    err = estimate[mask] - truth[mask]
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))), float(np.max(np.abs(err)))


def _scenario_table(quick: bool, linear_model, instant_model) -> None:
    rng = np.random.default_rng(7)
    LinearEstimator(linear_model).update(
        np.arange(3.0), np.ones((3, 1))
    )  # warm-up: first-call costs not timed
    print("\nforce estimators on known truth (typical sensor, contact term on, Gaussian conductance noise)")
    header = f"{'scenario':<38} {'estimator':<26} {'ns/sample':>10} {'rms_N':>8} {'max_N':>8}"
    print(header)
    print("-" * len(header))
    for base_name, generator, cutoff_hz, noise_s in SCENARIOS:
        name = f"{base_name}, {noise_s:.0e} S"
        t, truth = generator(quick)
        clean = conductance_from_force(t, truth, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        noisy = np.maximum(clean + rng.normal(0.0, noise_s, t.size), 0.0)
        rate_hz = 1.0 / float(np.median(np.diff(t)))
        # Score where the truth is loaded: at 0 N the contact term makes any reading ambiguous by design.
        loaded = truth > 0.0
        rows = []
        lin = LinearEstimator(linear_model)
        est, dt = _timed(lambda lin=lin, t=t, c=noisy: lin.update(t, c[:, None])[:, 0])
        rows.append(("linear, paper cal.", dt, est))
        lin = LinearEstimator(instant_model)
        est, dt = _timed(lambda lin=lin, t=t, c=noisy: lin.update(t, c[:, None])[:, 0])
        rows.append(("linear, instant cal.", dt, est))
        if t.size <= (2500 if quick else NAIVE_MAX_SAMPLES):
            est, dt = _timed(
                lambda t=t, c=noisy: _naive_superposition_inverse(
                    t, c, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS
                )
            )
            rows.append(("naive superposition O(N²)", dt, est))
        for interp in ("hold", "linear"):
            sls = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS, interp=interp)
            est, dt = _timed(lambda sls=sls, t=t, c=noisy: sls.update(t, c[:, None])[:, 0])
            rows.append((f"recursive SLS ({interp})", dt, est))
        lam = tikhonov_lambda(rate_hz, cutoff_hz, order=2)
        smoothed, dt_s = _timed(lambda e=rows[-2][2], lam=lam: smooth_tikhonov(e, lam, 2))
        rows.append((f"SLS + Tikhonov {cutoff_hz:g} Hz", rows[-2][1] + dt_s, smoothed))
        for label, dt, est in rows:
            rms, peak = _errors(est, truth, loaded)
            print(f"{name:<38} {label:<26} {dt / t.size * 1e9:10.0f} {rms:8.4f} {peak:8.4f}")
    print(
        "The SLS error is the noise floor (≈ E0·A × strain noise); the linear model's error is the creep it cannot"
        " see. The smoother only trades noise for bias at edges: it pays off only when noise dominates."
    )


def _pulse_length_table(linear_model, instant_model) -> None:
    """Where linear is good enough: error against contact length (one pulse of 3 N, noise-free)."""
    print(
        "\nlinear vs creep-corrected on one 3 N contact of given length (noise-free, 30 Hz); RMS error in N"
    )
    header = f"{'contact_s':>10} {'lin_paper_cal':>14} {'lin_instant_cal':>16} {'sls':>10}"
    print(header)
    print("-" * len(header))
    for length in (0.1, 1.0, 10.0, 30.0, 100.0, 300.0):
        t = np.arange(0.0, length + 5.0, 1 / 30)
        truth = np.where((t >= 1.0) & (t < 1.0 + length), 3.0, 0.0)
        cond = conductance_from_force(t, truth, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        loaded = truth > 0
        lin = LinearEstimator(linear_model).update(t, cond[:, None])[:, 0]
        inst = LinearEstimator(instant_model).update(t, cond[:, None])[:, 0]
        sls = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS).update(t, cond[:, None])[:, 0]
        lin_rms, _ = _errors(lin, truth, loaded)
        inst_rms, _ = _errors(inst, truth, loaded)
        sls_rms, _ = _errors(sls, truth, loaded)
        print(f"{length:10.1f} {lin_rms:14.4f} {inst_rms:16.4f} {sls_rms:10.2e}")
    print(
        "A linear model calibrated on the settled reading (the paper's 225–300 s) reads every short contact ~20 % low;"
        " calibrated on the instantaneous reading it is good for contacts ≪ τ and drifts on longer ones."
    )


def _force_dependent_table() -> None:
    """The paper's parameters grow with force; the estimator uses them at one reference force (3.5 N)."""
    p = TYPICAL_SLS
    e0, e1, mu1 = float(p.E0_Pa), float(p.E1_Pa), float(p.mu1_Pa_s)  # one sensor
    # ±25 % over the calibrated range, all three parameters rising with force (Fig. 9 iii)
    slope = 0.5 / 3.5
    trend = SLSTrend(
        E0_Pa=(e0 * (1 - 0.5), e0 * slope),
        E1_Pa=(e1 * (1 - 0.5), e1 * slope),
        mu1_Pa_s=(mu1 * (1 - 0.5), mu1 * slope),
    )
    reference = trend.at(3.5)
    print("\nforce-dependent parameters (truth: E0, E1, mu1 ∝ (0.5 + F/7 N), i.e. ±25 % over 1.75–5.25 N);")
    print(
        "estimators: fixed parameters at the reference force 3.5 N, and the force-dependent inverse (noise-free)"
    )
    header = f"{'record':<24} {'fixed_rms_N':>12} {'fixed_max_N':>12} {'max_rel':>8} {'trend_max_N':>12} {'trend_ns':>9}"
    print(header)
    print("-" * len(header))
    records = [
        (
            f"hold {f} N, 370 s",
            np.arange(0.0, 370.0, 1 / 6),
            np.where(np.arange(0.0, 370.0, 1 / 6) >= 5.0, f, 0.0),
        )
        for f in TYPICAL_FORCES_N
    ]
    records.append(("contact pulses 1–5 N", *_pulses(True)))
    for label, t, truth in records:
        strain = strain_from_force_trend(t, truth, trend, TYPICAL_AREA_M2)
        cond = conductance_from_strain(strain, truth, DEFAULT_PHYSICS)
        est = force_from_conductance(t, cond, reference, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        exact, dt = _timed(
            lambda t=t, cond=cond: force_from_conductance_trend(
                t, cond, trend, TYPICAL_AREA_M2, DEFAULT_PHYSICS
            )
        )
        loaded = truth > 0
        rms, peak = _errors(est, truth, loaded)
        _, trend_peak = _errors(exact.force_n, truth, loaded)
        rel = peak / float(np.max(truth))
        print(f"{label:<24} {rms:12.4f} {peak:12.4f} {rel:8.3f} {trend_peak:12.1e} {dt / t.size * 1e9:9.0f}")


def _throughput_table(quick: bool) -> None:
    n_sensors, rate_hz = 1024, 1000.0
    seconds = 0.5 if quick else 2.0
    block = 1000
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    rng = np.random.default_rng(3)
    phase = rng.uniform(0, 2 * np.pi, n_sensors)
    force = 3.0 + 1.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + phase)
    print(
        f"\nthroughput: {n_sensors} sensors at {rate_hz:g} Hz, {seconds:g} s in blocks of {block} samples, one core"
    )
    header = f"{'path':<34} {'M sensor-samples/s':>19} {'max_err_N':>10}"
    print(header)
    print("-" * len(header))
    for contact in (False, True):
        phys = DEFAULT_PHYSICS if contact else DEFAULT_PHYSICS.without_contact()
        label = "with contact" if contact else "no contact"
        for interp in ("hold", "linear"):
            dt = np.inf
            for _ in range(REPEATS):
                cond, dt_once = _timed(
                    lambda phys=phys, interp=interp: conductance_from_force(
                        t, force, TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp
                    )
                )
                dt = min(dt, dt_once)
            print(f"{'forward ' + label + ' (' + interp + ')':<34} {force.size / dt / 1e6:19.1f} {'':>10}")
            est = SLSEstimator(TYPICAL_SLS, TYPICAL_AREA_M2, phys, interp=interp, n_sensors=n_sensors)
            est.update(t[:block], cond[:block])  # warm-up (allocations, first-call costs)
            out = np.empty_like(cond)
            dt = np.inf
            for _ in range(REPEATS):  # best of: the machine is shared, the minimum is the code's own cost
                est.reset()
                start = time.process_time()
                for lo in range(0, t.size, block):
                    out[lo : lo + block] = est.update(t[lo : lo + block], cond[lo : lo + block])
                dt = min(dt, time.process_time() - start)
            err = float(np.max(np.abs(out - force)))
            print(f"{'inverse ' + label + ' (' + interp + ')':<34} {force.size / dt / 1e6:19.1f} {err:10.1e}")
    print("target: ≥ 10 M sensor-samples/s for the inverse without the contact term")
    # The O(N²) reference at this scale: time two lengths, fit t = a·N + b·N² (per-step overhead + the growing sum).
    sizes = (1000, 4000) if quick else (2000, 8000)
    times = []
    for n_short in sizes:
        tt = np.arange(n_short) / rate_hz
        ff = 3.0 + np.sin(tt)
        cc = conductance_from_force(tt, ff, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS)
        _, dt = _timed(
            lambda tt=tt, cc=cc: _naive_superposition_inverse(
                tt, cc, TYPICAL_SLS, TYPICAL_AREA_M2, DEFAULT_PHYSICS
            )
        )
        times.append(dt)
    (n1, n2), (t1, t2) = sizes, times
    b = max((t2 / n2 - t1 / n1) / (n2 - n1), 0.0)
    a = max(t1 / n1 - b * n1, 0.0)
    n_long = 370_000
    print(
        f"naive superposition: {t1:.2f} s for {n1} samples, {t2:.2f} s for {n2} → ~{(a * n_long + b * n_long**2) / 60:.0f}"
        f" min per sensor for 370 s at 1 kHz (fit a·N + b·N²); the recursion: one pass"
    )


def run(quick: bool) -> None:
    linear_model = _calibrated_linear()
    instant_model = _calibrated_linear(INSTANT_WINDOW_S)
    print(
        f"typical sensor: E0={TYPICAL_SLS.E0_Pa:.3g} Pa, E1={TYPICAL_SLS.E1_Pa:.3g} Pa, mu1={TYPICAL_SLS.mu1_Pa_s:.3g}"
        f" Pa·s (τ={TYPICAL_SLS.tau_s:.0f} s), A={TYPICAL_AREA_M2} m²; linear fit m={linear_model.m_S_per_N:.4g} S/N,"
        f" d={linear_model.d_S:.4g} S"
    )
    _scenario_table(quick, linear_model, instant_model)
    _pulse_length_table(linear_model, instant_model)
    _force_dependent_table()
    _throughput_table(quick)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter records and stream")
    run(parser.parse_args().quick)
