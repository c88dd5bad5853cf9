"""The quiet-port check (vdm_aero.nav.ports_frontend.QuietPorts) on synthetic port streams: ports that breathe
with a turbulent flow, each with its own sensitivity, are never called quiet; a line blocked at its orifice
is, alone and within seconds; nothing is judged in calm flow or before the shares are learnt; a port that
breathes again comes back; healthy ports whose share changes with α (slow flight) or with a pitch manoeuvre
are not called quiet."""

from __future__ import annotations

import math

import numpy as np

from vdm_aero.nav.ports_frontend import QuietPorts

N = 12
RATE_HZ = 50.0
NOISE_PA = 0.1


ALPHA0_RAD = math.radians(3.0)  # cruise


def _flow(
    t: np.ndarray,
    rng: np.random.Generator,
    gust_pa: float = 4.0,
    alpha_mean_rad: np.ndarray | float = ALPHA0_RAD,
    shapes: dict[int, tuple[float, float, float]] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(Δp (len(t), N), α (len(t),) [rad]): q̄ ≈ 200 Pa and α moved by turbulence (1 s correlated) about
    ``alpha_mean_rad``, each port with its own Cp at cruise and α sensitivity (a stagnation port breathes more
    than a shoulder one), plus the transducer's noise. ``shapes``: port → (Cp, dCp/dα, d²Cp/dα²) at cruise,
    for a port whose Cp(α) is given rather than drawn."""
    cp = rng.uniform(-1.2, 1.0, N)
    dcp_da = rng.uniform(-3.0, 3.0, N)
    d2cp_da2 = np.zeros(N)
    for port, shape in (shapes or {}).items():
        cp[port], dcp_da[port], d2cp_da2[port] = shape
    q = np.full(len(t), 200.0)
    a = np.zeros(len(t))
    phi = math.exp(-1.0 / RATE_HZ)
    for k in range(1, len(t)):
        q[k] = 200.0 + (q[k - 1] - 200.0) * phi + gust_pa * math.sqrt(1 - phi**2) * rng.standard_normal()
        a[k] = a[k - 1] * phi + 0.01 * math.sqrt(1 - phi**2) * rng.standard_normal()
    alpha = alpha_mean_rad + a
    da = alpha[:, None] - ALPHA0_RAD
    dp = q[:, None] * (cp + dcp_da * da + 0.5 * d2cp_da2 * da**2) + NOISE_PA * rng.standard_normal((len(t), N))
    return dp, alpha


def _run(t: np.ndarray, flow: tuple[np.ndarray, np.ndarray]) -> tuple[QuietPorts, list[tuple[float, int, bool]]]:
    dp, alpha = flow
    qp = QuietPorts(N, NOISE_PA)
    events = []
    for k in range(len(t)):
        was = qp.quiet.copy()
        qp.observe(float(t[k]), dp[k], float(alpha[k]))
        events += [(float(t[k]), int(i), bool(qp.quiet[i])) for i in np.flatnonzero(qp.quiet != was)]
    return qp, events


def _block(
    t: np.ndarray, flow: tuple[np.ndarray, np.ndarray], port: int, t0: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The port's line blocked at ``t0``: the trapped value leaking away (τ 40 s), with the transducer's noise."""
    dp, alpha = flow
    out = dp.copy()
    after = t >= t0
    out[after, port] = dp[np.argmax(after), port] * np.exp(-(t[after] - t0) / 40.0) + NOISE_PA * rng.standard_normal(
        int(after.sum()))  # fmt: skip
    return out, alpha


def test_ports_breathing_with_a_turbulent_flow_are_never_called_quiet() -> None:
    t = np.arange(0.0, 900.0, 1.0 / RATE_HZ)
    for seed in range(3):
        _, events = _run(t, _flow(t, np.random.default_rng(seed)))
        assert events == []


def test_a_blocked_line_is_called_quiet_alone_within_seconds() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 300.0, 1.0 / RATE_HZ)
    qp, events = _run(t, _block(t, _flow(t, rng), 5, 150.0, rng))
    assert [(i, quiet) for _, i, quiet in events] == [(5, True)]
    assert 150.0 < events[0][0] < 150.0 + 10.0
    assert qp.quiet.tolist() == [i == 5 for i in range(N)]


def test_nothing_is_judged_in_calm_flow_or_before_the_shares_are_learnt() -> None:
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 300.0, 1.0 / RATE_HZ)
    calm, alpha = _flow(t, rng, gust_pa=0.0)  # still air: the ports move by their noise alone
    calm[:, 1] = calm[0, 1] + NOISE_PA * rng.standard_normal(len(t))  # held: indistinguishable here
    _, events = _run(t, (calm, alpha))
    assert events == []
    # a line blocked in the first seconds of turbulent flow: the shares are still being learnt
    _, events = _run(t, _block(t, _flow(t, rng), 3, 10.0, rng))
    assert all(t_ev >= QuietPorts.WARMUP_S for t_ev, _, _ in events)


def test_a_port_that_breathes_again_comes_back() -> None:
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 400.0, 1.0 / RATE_HZ)
    flow = _flow(t, rng)
    dp, alpha = _block(t, flow, 9, 150.0, rng)
    dp[t >= 220.0, 9] = flow[0][t >= 220.0, 9]  # the water blown out of the line
    qp, events = _run(t, (dp, alpha))
    assert [(i, quiet) for _, i, quiet in events] == [(9, True), (9, False)]
    assert 220.0 + QuietPorts.BACK_S <= events[1][0] < 240.0
    assert not qp.quiet.any()


def test_a_port_that_stops_breathing_in_slow_flight_is_not_called_quiet_but_a_blocked_one_still_is() -> None:
    """Port 0 is at the stagnation point in cruise (Cp 0.9: it breathes with every gust) and, at α = 12° in slow
    flight, where its Cp(α) has a flat zero (the stagnation point has moved away): it hardly moves there, with
    nothing wrong. One share for every condition calls it quiet; its share per α band does not, and the band,
    once learnt, still finds a line blocked there."""
    rng = np.random.default_rng(10)
    t = np.arange(0.0, 700.0, 1.0 / RATE_HZ)
    slow_rad = math.radians(12.0)
    alpha_mean = np.where(t < 300.0, ALPHA0_RAD, slow_rad)  # a level deceleration to slow flight at 300 s
    k = 0.9 / (slow_rad - ALPHA0_RAD) ** 2  # Cp₀(α) = k (α − 12°)²: 0.9 in cruise, a flat zero at 12°
    flow = _flow(t, rng, alpha_mean_rad=alpha_mean, shapes={0: (0.9, -2.0 * k * (slow_rad - ALPHA0_RAD), 2.0 * k)})
    _, events = _run(t, flow)
    assert events == []
    _, events = _run(t, _block(t, flow, 5, 550.0, rng))
    assert [(i, quiet) for _, i, quiet in events] == [(5, True)]
    assert 550.0 < events[0][0] < 550.0 + 10.0


def test_a_pitch_manoeuvre_calls_no_port_quiet_and_a_blocked_one_is_found_after_it() -> None:
    """Port 0 barely feels α (dCp/dα = 0): in a pitch oscillation (±8°, 0.5 Hz, 30 s) every other port's
    reading swings with α and port 0's share of the common activity falls far under its cruise share, with
    nothing wrong. No verdict while α moves that much; a line blocked during the manoeuvre is found after it."""
    rng = np.random.default_rng(12)
    t = np.arange(0.0, 500.0, 1.0 / RATE_HZ)
    manoeuvre = (t >= 300.0) & (t < 330.0)
    alpha_mean = ALPHA0_RAD + np.where(manoeuvre, math.radians(8.0) * np.sin(2.0 * math.pi * 0.5 * (t - 300.0)), 0.0)
    flow = _flow(t, rng, alpha_mean_rad=alpha_mean, shapes={0: (0.9, 0.0, 0.0)})
    _, events = _run(t, flow)
    assert events == []
    _, events = _run(t, _block(t, flow, 5, 315.0, rng))
    assert [(i, quiet) for _, i, quiet in events] == [(5, True)]
    assert 330.0 <= events[0][0] < 330.0 + 15.0


def test_a_lossy_links_holes_call_no_port_quiet_and_a_blocked_one_is_still_found() -> None:
    """The frames come in bursts (0.3 s delivered, 1 s lost: a lossy link). A change across a hole is one over
    1.3 s, not 0.1 s: a port that breathes with the slow flow (q̄ swinging ±100 Pa over 10 s) changes ~100×
    more over it, one in the propwash's buffeting (white, the same 0.1-s activity) no more. Taken as a 0.1-s
    change, the buffeting port's share fell to ~1 % of its own and it was called quiet. Only the changes
    inside a burst count now, so it is not; a line blocked in the same bursts still is, within 10 s of the
    frames delivered."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 320.0, 1.0 / RATE_HZ)
    q = 200.0 + 100.0 * np.sin(2.0 * math.pi * t / 10.0)
    cp = rng.uniform(0.4, 1.0, N)
    dp = q[:, None] * cp + NOISE_PA * rng.standard_normal((len(t), N))
    dp[:, 11] = 2.5 * rng.standard_normal(len(t))  # a port in the propwash: Cp ≈ 0, buffeted
    alpha = ALPHA0_RAD + 1e-3 * rng.standard_normal(len(t))
    _, events = _run(t, (dp, alpha))
    assert events == []  # the same flow, every frame: no port is quiet
    lossy = (t < 150.0) | (np.mod(t - 150.0, 1.3) < 0.3)
    _, events = _run(t[lossy], (dp[lossy], alpha[lossy]))
    assert events == [], events
    blocked = dp.copy()
    blocked[t >= 200.0, 3] = blocked[int(np.searchsorted(t, 200.0)), 3]  # the line holds the air it trapped
    _, events = _run(t[lossy], (blocked[lossy], alpha[lossy]))
    assert [(i, q) for _, i, q in events] == [(3, True)], events
    # within 10 s of frames delivered (the activity is learnt from the bursts alone: 0.3 s of every 1.3)
    assert events[0][0] - 200.0 < 10.0 * 1.3 / 0.3
    # a slow stream's every frame is no hole: at 5 Hz (a log's rate) the blocked line is found as well
    slow = slice(None, None, round(RATE_HZ / 5.0))
    _, events = _run(t[slow], (blocked[slow], alpha[slow]))
    assert [(i, q) for _, i, q in events] == [(3, True)], events


def test_a_pitch_down_into_a_learnt_band_calls_no_port_quiet() -> None:
    """Port 0 barely feels α (Cp 0.9 throughout); every other port's dCp/dα is six times larger at 5° than at 1°, so
    at 5° port 0's share of the common activity is ~1/36 of its cruise share, with nothing wrong. The aircraft
    cruises at 1°, flies 30 s at 5° (too short to learn that band: no verdict there), and pitches back down
    within 0.5 s, too briefly to count as a manoeuvre. The activities are 2-s means: a second after α is back,
    they still hold the last band's flow, and judged against the cruise band's share port 0 was called quiet
    (the benchmark's manoeuvring flights, three times in 5.6 h). Its band is now that of α's own 2-s mean, and
    α must be in it too. A line blocked in cruise after the manoeuvre is still found."""
    t = np.arange(0.0, 400.0, 1.0 / RATE_HZ)
    lo, hi = math.radians(1.0), math.radians(5.0)
    alpha_mean = lo + (hi - lo) * (np.clip((t - 300.0) / 0.5, 0.0, 1.0) - np.clip((t - 332.0) / 0.5, 0.0, 1.0))
    for seed in (14, 16, 17):
        rng = np.random.default_rng(seed)
        slope = rng.choice([-1.0, 1.0], N) * rng.uniform(1.0, 2.0, N)  # dCp/dα at 1° [1/rad]
        curve = 5.0 * slope / (hi - lo)  # six times the slope at 5°
        shapes = {i: (float(rng.uniform(-1.0, 1.0)), float(slope[i] + curve[i] * (ALPHA0_RAD - lo)), float(curve[i]))
                  for i in range(1, N)}  # fmt: skip
        shapes[0] = (0.9, 0.0, 0.0)
        flow = _flow(t, rng, alpha_mean_rad=alpha_mean, shapes=shapes)
        _, events = _run(t, flow)
        assert events == [], (seed, events)
        _, events = _run(t, _block(t, flow, 5, 360.0, rng))
        assert [(i, quiet) for _, i, quiet in events] == [(5, True)], (seed, events)
        assert 360.0 < events[0][0] < 360.0 + 10.0


def test_a_blocked_port_is_not_readmitted_in_a_band_not_yet_learnt() -> None:
    """Port 5 barely breathes in cruise (Cp 0.05, flat in α there) and breathes hard at 7°, where its Cp(α) is
    steep. Its line is blocked in cruise, leaking 10 % of the flow's changes through, and called quiet. Then the
    aircraft flies 40 s at 7°, a band not flown before: its shares start from the cruise band's, and the leak,
    against port 5's tiny cruise share, reads 0.3–0.5 of it, over the share for coming back (the benchmark's
    blocked ports at 0.3–0.45 in a band learnt for 18 s, `ports-blocked` seed 3, 2026-11-30). Coming back is a
    verdict and now waits for a learnt band, as being called quiet does; without that the port came back ~7 s
    into the new band and was called quiet again after it."""
    t = np.arange(0.0, 420.0, 1.0 / RATE_HZ)
    hi = math.radians(7.0)
    alpha_mean = ALPHA0_RAD + (hi - ALPHA0_RAD) * (np.clip((t - 300.0) / 2.0, 0, 1) - np.clip((t - 340.0) / 2.0, 0, 1))
    for seed in (1, 2, 3):
        rng = np.random.default_rng(seed)
        dp, alpha = _flow(t, rng, alpha_mean_rad=alpha_mean, shapes={5: (0.05, 0.0, 60.0)})
        after = t >= 200.0
        dp[after, 5] = 0.9 * dp[np.argmax(after), 5] + 0.1 * dp[after, 5]
        _, events = _run(t, (dp, alpha))
        assert [(i, quiet) for _, i, quiet in events] == [(5, True)], (seed, events)
        assert 200.0 < events[0][0] < 200.0 + 10.0
