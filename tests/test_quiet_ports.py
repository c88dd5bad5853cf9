"""The quiet-port check (vdm_aero.nav.ports_frontend.QuietPorts) on synthetic port streams: ports that breathe
with a turbulent flow, each with its own sensitivity, are never called quiet; a line blocked at its orifice
is, alone and within seconds; nothing is judged in calm flow or before the shares are learnt; a port that
breathes again comes back."""

from __future__ import annotations

import math

import numpy as np

from vdm_aero.nav.ports_frontend import QuietPorts

N = 12
RATE_HZ = 50.0
NOISE_PA = 0.1


def _flow(t: np.ndarray, rng: np.random.Generator, gust_pa: float = 4.0) -> np.ndarray:
    """Δp (len(t), N): q̄ ≈ 200 Pa and α moved by turbulence (1 s correlated), each port with its own Cp and α
    sensitivity (a stagnation port breathes more than a shoulder one), plus the transducer's noise."""
    cp = rng.uniform(-1.2, 1.0, N)
    dcp_da = rng.uniform(-3.0, 3.0, N)
    q = np.full(len(t), 200.0)
    a = np.zeros(len(t))
    phi = math.exp(-1.0 / RATE_HZ)
    for k in range(1, len(t)):
        q[k] = 200.0 + (q[k - 1] - 200.0) * phi + gust_pa * math.sqrt(1 - phi**2) * rng.standard_normal()
        a[k] = a[k - 1] * phi + 0.01 * math.sqrt(1 - phi**2) * rng.standard_normal()
    return q[:, None] * (cp + dcp_da * a[:, None]) + NOISE_PA * rng.standard_normal((len(t), N))


def _run(t: np.ndarray, dp: np.ndarray) -> tuple[QuietPorts, list[tuple[float, int, bool]]]:
    qp = QuietPorts(N, NOISE_PA)
    events = []
    for k in range(len(t)):
        was = qp.quiet.copy()
        qp.observe(float(t[k]), dp[k])
        events += [(float(t[k]), int(i), bool(qp.quiet[i])) for i in np.flatnonzero(qp.quiet != was)]
    return qp, events


def _block(t: np.ndarray, dp: np.ndarray, port: int, t0: float, rng: np.random.Generator) -> np.ndarray:
    """The port's line blocked at ``t0``: the trapped value leaking away (τ 40 s), with the transducer's noise."""
    out = dp.copy()
    after = t >= t0
    out[after, port] = dp[np.argmax(after), port] * np.exp(-(t[after] - t0) / 40.0) + NOISE_PA * rng.standard_normal(
        int(after.sum()))  # fmt: skip
    return out


def test_ports_breathing_with_a_turbulent_flow_are_never_called_quiet() -> None:
    t = np.arange(0.0, 900.0, 1.0 / RATE_HZ)
    for seed in range(3):
        _, events = _run(t, _flow(t, np.random.default_rng(seed)))
        assert events == []


def test_a_blocked_line_is_called_quiet_alone_within_seconds() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 300.0, 1.0 / RATE_HZ)
    dp = _block(t, _flow(t, rng), 5, 150.0, rng)
    qp, events = _run(t, dp)
    assert [(i, quiet) for _, i, quiet in events] == [(5, True)]
    assert 150.0 < events[0][0] < 150.0 + 10.0
    assert qp.quiet.tolist() == [i == 5 for i in range(N)]


def test_nothing_is_judged_in_calm_flow_or_before_the_shares_are_learnt() -> None:
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 300.0, 1.0 / RATE_HZ)
    calm = _flow(t, rng, gust_pa=0.0)  # still air: the ports move by their noise alone
    calm[:, 1] = calm[0, 1] + NOISE_PA * rng.standard_normal(len(t))  # held: indistinguishable here
    _, events = _run(t, calm)
    assert events == []
    # a line blocked in the first seconds of turbulent flow: the shares are still being learnt
    dp = _block(t, _flow(t, rng), 3, 10.0, rng)
    _, events = _run(t, dp)
    assert all(t_ev >= QuietPorts.WARMUP_S for t_ev, _, _ in events)


def test_a_port_that_breathes_again_comes_back() -> None:
    rng = np.random.default_rng(8)
    t = np.arange(0.0, 400.0, 1.0 / RATE_HZ)
    flow = _flow(t, rng)
    dp = _block(t, flow, 9, 150.0, rng)
    dp[t >= 220.0, 9] = flow[t >= 220.0, 9]  # the water blown out of the line
    qp, events = _run(t, dp)
    assert [(i, quiet) for _, i, quiet in events] == [(9, True), (9, False)]
    assert 220.0 + QuietPorts.BACK_S <= events[1][0] < 240.0
    assert not qp.quiet.any()
