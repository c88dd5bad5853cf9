"""Guidance and control of the simulated aircraft: routes, L1 path following, TECS, attitude loops.

The world's autopilot flies on the TRUE state (it is part of the plant that produces realistic flights
for the navigation under test, not an estimator): an ArduPlane-like cascade at the control rate.

* **Routes**: cyclic waypoint lists, a loiter circle, or a survey ("lawnmower") pattern that expands into
  waypoints. Heights are above home; each route has its airspeed demand.
* **Lateral**: L1 guidance (Park, Deyst & How, "A New Nonlinear Guidance Logic for Trajectory
  Tracking", AIAA GNC 2004): a reference point on the path at distance L1 = ζ·P·V_g/π ahead (ArduPlane's
  NAVL1_PERIOD/NAVL1_DAMPING form), lateral acceleration a = 2·V_g²/L1·sin η, bank φ = atan(a/g).
  On a circle the reference point is the intersection of the L1 circle with the loiter circle, so on the
  circle a = V_g²/R exactly; from outside the aircraft flies to the tangent point.
* **Longitudinal**: a total-energy controller (TECS, Lambregts 1983): throttle drives the specific total
  energy rate ḣ + V·V̇/g to its demand (feed-forward from the propeller's thrust slope at trim plus PI),
  pitch drives the energy-balance rate ḣ − V·V̇/g (feed-forward γ plus PI). V̇ is the ground acceleration
  along the velocity (smooth in turbulence, unlike a differentiated airspeed).
* **Inner loops**: the bank demand slewed at ``max_roll_rate_rad_s`` (ArduPlane limits its roll rate
  the same way), roll PI + rate damping, pitch PI + rate damping with the coordinated-turn pitch
  rate as feed-forward, yaw damper on r − r_turn plus sideslip PI (coordinated turns: β → 0). Surface gains scale with
  (V_trim/V)² (constant control power over the speed range).

Control signs follow :mod:`sim.flight.actuators`: aileron > 0 rolls left, elevator > 0 pitches down,
rudder > 0 yaws left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from sim.flight.environment import G0_M_S2

__all__ = [
    "AUTOPILOT_GAINS",
    "Autopilot",
    "AutopilotGains",
    "LoiterRoute",
    "NavState",
    "Route",
    "SurveyRoute",
    "TrimPoint",
    "WaypointRoute",
    "l1_lateral_accel_circle",
    "l1_lateral_accel_segment",
]


# ---------------------------------------------------------------------------------------- routes
@dataclass(frozen=True)
class WaypointRoute:
    """Waypoints (north [m], east [m], height above home [m]) flown in order and repeated; a waypoint is
    reached when the aircraft passes the line through it perpendicular to the leg or comes within
    ``acceptance_m``."""

    waypoints: tuple[tuple[float, float, float], ...]
    airspeed_m_s: float
    acceptance_m: float
    type: str = "waypoints"


@dataclass(frozen=True)
class LoiterRoute:
    """A circle of ``radius_m`` about (north, east) [m] at ``height_m`` above home, clockwise seen from
    above (right turns) when ``clockwise``."""

    centre_ne_m: tuple[float, float]
    radius_m: float
    height_m: float
    clockwise: bool
    airspeed_m_s: float
    type: str = "loiter"


@dataclass(frozen=True)
class SurveyRoute:
    """A lawnmower pattern over the rectangle that starts at ``origin_ne_m``, ``length_m`` along
    ``heading_deg`` by ``width_m`` to its right, lines ``spacing_m`` apart, flown back and forth and
    repeated."""

    origin_ne_m: tuple[float, float]
    length_m: float
    width_m: float
    spacing_m: float
    heading_deg: float
    height_m: float
    airspeed_m_s: float
    acceptance_m: float
    type: str = "survey"

    def waypoints(self) -> tuple[tuple[float, float, float], ...]:
        """The pattern's waypoints (line ends, alternating direction)."""
        h = math.radians(self.heading_deg)
        along = (math.cos(h), math.sin(h))
        right = (-math.sin(h), math.cos(h))
        n_lines = math.floor(self.width_m / self.spacing_m + 1e-9) + 1
        out: list[tuple[float, float, float]] = []
        for i in range(n_lines):
            off = i * self.spacing_m
            s0, s1 = (0.0, self.length_m) if i % 2 == 0 else (self.length_m, 0.0)
            for s in (s0, s1):
                out.append(
                    (
                        self.origin_ne_m[0] + s * along[0] + off * right[0],
                        self.origin_ne_m[1] + s * along[1] + off * right[1],
                        self.height_m,
                    )
                )
        return tuple(out)


Route = WaypointRoute | LoiterRoute | SurveyRoute


# ---------------------------------------------------------------------------------------- gains
@dataclass(frozen=True)
class AutopilotGains:
    """Gains and limits of the cascade (SI: rad, m, s). Surface gains are at the trim airspeed."""

    l1_period_s: float
    l1_damping: float
    max_bank_rad: float
    max_roll_rate_rad_s: float  # slew limit of the bank demand
    height_gain_per_s: float  # ḣ demand per metre of height error
    max_climb_m_s: float
    max_sink_m_s: float
    speed_gain_per_s: float  # V̇ demand per m/s of airspeed error
    max_accel_m_s2: float
    throttle_p: float  # throttle per m/s of total-energy-rate error
    throttle_i: float  # throttle per m of integrated total-energy-rate error
    pitch_energy_p: float  # rad of pitch per rad of balance-rate error (error/V)
    pitch_energy_i: float  # [1/s]
    max_pitch_rad: float
    min_pitch_rad: float
    roll_p: float  # aileron rad per rad of bank error
    roll_i: float  # [1/s]
    roll_rate_d: float  # aileron rad per rad/s of roll rate
    pitch_p: float  # elevator rad per rad of pitch error
    pitch_i: float  # [1/s]
    pitch_rate_d: float  # elevator rad per rad/s of pitch-rate error
    yaw_rate_d: float  # rudder rad per rad/s of yaw-rate error
    sideslip_p: float  # rudder rad per rad of sideslip
    sideslip_i: float  # rudder rad per rad·s of integrated sideslip
    source: str


AUTOPILOT_GAINS: Final = {
    "uav-2m": AutopilotGains(
        l1_period_s=18.0,
        l1_damping=0.75,
        max_bank_rad=math.radians(35.0),
        max_roll_rate_rad_s=math.radians(45.0),
        height_gain_per_s=0.25,
        max_climb_m_s=3.0,
        max_sink_m_s=3.0,
        speed_gain_per_s=0.4,
        max_accel_m_s2=2.0,
        throttle_p=0.1,
        throttle_i=0.03,
        pitch_energy_p=1.0,
        pitch_energy_i=0.3,
        max_pitch_rad=math.radians(20.0),
        min_pitch_rad=math.radians(-15.0),
        roll_p=0.8,
        roll_i=0.2,
        roll_rate_d=0.02,
        pitch_p=0.3,
        pitch_i=0.1,
        pitch_rate_d=0.02,
        yaw_rate_d=0.15,
        sideslip_p=0.3,
        sideslip_i=0.5,
        source="tuned on the uav-2m vehicle's linearised dynamics at 18 m/s (roll pole ≈ 4 rad/s, pitch "
        "attitude crossover ≈ 3 rad/s, yaw damper doubling the Dutch-roll damping); ArduPlane defaults for L1 "
        "damping and TECS limits; bank demand slewed at 45°/s",
    ),
}
"""Named autopilot tunings (one per vehicle preset)."""


@dataclass(frozen=True)
class TrimPoint:
    """The trimmed level-flight point the autopilot is built around."""

    airspeed_m_s: float
    alpha_rad: float
    beta_rad: float
    aileron_rad: float
    elevator_rad: float
    rudder_rad: float
    throttle: float
    thrust_per_throttle_n: float  # dT/dδ_t at trim [N]


@dataclass(frozen=True)
class NavState:
    """What the autopilot reads (truth): NED position [m] and ground velocity [m/s], NED ground
    acceleration [m/s²], Euler angles, body rates [rad/s], airspeed [m/s] and sideslip [rad]."""

    north_m: float
    east_m: float
    down_m: float
    v_n: float
    v_e: float
    v_d: float
    a_n: float
    a_e: float
    a_d: float
    roll: float
    pitch: float
    yaw: float
    p: float
    q: float
    r: float
    airspeed_m_s: float
    beta_rad: float


# ------------------------------------------------------------------------------------------ L1
def _eta_accel(px: float, py: float, vx: float, vy: float, rx: float, ry: float, l1: float) -> float:
    """a = 2V²/L1·sin η towards the reference point (rx, ry) (|η| capped at 90°; positive = turn right)."""
    dx, dy = rx - px, ry - py
    v2 = vx * vx + vy * vy
    eta = math.atan2(vx * dy - vy * dx, vx * dx + vy * dy)
    s = 1.0 if eta > 0.5 * math.pi else -1.0 if eta < -0.5 * math.pi else math.sin(eta)
    return 2.0 * v2 / l1 * s


def l1_lateral_accel_segment(
    pos: tuple[float, float], vel: tuple[float, float], a: tuple[float, float], b: tuple[float, float], l1: float
) -> tuple[float, float]:
    """(lateral acceleration [m/s²], along-track distance remaining to b [m]) for the leg a → b (NE)."""
    tx, ty = b[0] - a[0], b[1] - a[1]
    length = math.hypot(tx, ty)
    tx, ty = tx / length, ty / length
    apx, apy = pos[0] - a[0], pos[1] - a[1]
    along = apx * tx + apy * ty
    xt = tx * apy - ty * apx  # > 0: right of the track
    ahead = math.sqrt(l1 * l1 - xt * xt) if abs(xt) < l1 else 0.0
    s = along + ahead
    return _eta_accel(pos[0], pos[1], vel[0], vel[1], a[0] + s * tx, a[1] + s * ty, l1), length - along


def l1_lateral_accel_circle(
    pos: tuple[float, float],
    vel: tuple[float, float],
    centre: tuple[float, float],
    radius: float,
    direction: float,
    l1: float,
) -> float:
    """Lateral acceleration [m/s²] to join and follow a circle (``direction`` +1 clockwise from above)."""
    dx, dy = pos[0] - centre[0], pos[1] - centre[1]
    d = math.hypot(dx, dy)
    if d < 1e-6:
        dx, dy, d = 1.0, 0.0, 1.0
    ux, uy = dx / d, dy / d
    tx, ty = -direction * uy, direction * ux  # direction of travel at the radial direction u
    if abs(d - radius) < l1 and d > 1e-3:
        a = (radius * radius - l1 * l1 + d * d) / (2.0 * d)
        h = math.sqrt(max(radius * radius - a * a, 0.0))
        rx, ry = centre[0] + a * ux + h * tx, centre[1] + a * uy + h * ty
    elif d >= radius:
        ang = direction * math.acos(radius / d)  # tangent point, on the side that joins the circle forwards
        c, s = math.cos(ang), math.sin(ang)
        rx, ry = centre[0] + radius * (ux * c - uy * s), centre[1] + radius * (ux * s + uy * c)
    else:
        ang = direction * math.radians(60.0)  # deep inside: head out towards a point ahead on the circle
        c, s = math.cos(ang), math.sin(ang)
        rx, ry = centre[0] + radius * (ux * c - uy * s), centre[1] + radius * (ux * s + uy * c)
    return _eta_accel(pos[0], pos[1], vel[0], vel[1], rx, ry, l1)


# ------------------------------------------------------------------------------------- autopilot
def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class Autopilot:
    """Route → bank and energy demands → attitude → surface and throttle commands, at ``dt_s``."""

    def __init__(
        self,
        route: Route,
        gains: AutopilotGains,
        trim: TrimPoint,
        mass_kg: float,
        dt_s: float,
        gravity_m_s2: float = G0_M_S2,
    ) -> None:
        self.route = route
        self.gains = gains
        self.trim = trim
        self.mass_kg = mass_kg
        self.dt_s = dt_s
        self.g = gravity_m_s2
        self.waypoints: tuple[tuple[float, float, float], ...] = ()
        if isinstance(route, SurveyRoute):
            self.waypoints = route.waypoints()
        elif isinstance(route, WaypointRoute):
            self.waypoints = route.waypoints
        self.leg = 0  # flying from waypoints[leg − 1] (or the start) to waypoints[leg]
        self._leg_start: tuple[float, float] | None = None
        # feed-forward: throttle to hold a total-energy rate of 1 m/s is m·g/(V·dT/dδ_t)
        self._throttle_per_ste = mass_kg * gravity_m_s2 / (trim.airspeed_m_s * trim.thrust_per_throttle_n)
        self._i_thr = 0.0
        self._i_pitch = 0.0
        self._i_roll = 0.0
        self._i_theta = 0.0
        self._i_beta = 0.0
        self.roll_cmd = 0.0
        self.pitch_cmd = trim.alpha_rad
        self.height_demand_m = 0.0
        # scripted changes (calibration manoeuvres): the speed held and an offset on the route's height
        self.airspeed_demand_m_s = route.airspeed_m_s
        self.height_offset_m = 0.0

    def _lateral(self, s: NavState, l1: float) -> float:
        pos, vel = (s.north_m, s.east_m), (s.v_n, s.v_e)
        r = self.route
        if isinstance(r, LoiterRoute):
            self.height_demand_m = r.height_m
            return l1_lateral_accel_circle(pos, vel, r.centre_ne_m, r.radius_m, 1.0 if r.clockwise else -1.0, l1)
        assert isinstance(r, WaypointRoute | SurveyRoute)
        wps = self.waypoints
        for _ in range(len(wps)):  # advance past reached waypoints
            b = wps[self.leg]
            a = self._leg_start if self._leg_start is not None else wps[self.leg - 1][:2]
            if math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-6:
                self._advance(b)
                continue
            acc, remaining = l1_lateral_accel_segment(pos, vel, a, b[:2], l1)
            if remaining <= 0.0 or math.hypot(pos[0] - b[0], pos[1] - b[1]) < r.acceptance_m:
                self._advance(b)
                continue
            self.height_demand_m = b[2]
            return acc
        raise RuntimeError("route has no leg of non-zero length")

    def _advance(self, reached: tuple[float, float, float]) -> None:
        self._leg_start = reached[:2]
        self.leg = (self.leg + 1) % len(self.waypoints)

    def start_leg_from(self, north_m: float, east_m: float) -> None:
        """Fly the first leg from the start position (not from the last waypoint of the cycle)."""
        self._leg_start = (north_m, east_m)

    def update(self, s: NavState) -> tuple[float, float, float, float]:
        """Commands (aileron, elevator, throttle, rudder) for the current state."""
        g, k, dt, trim = self.g, self.gains, self.dt_s, self.trim
        vg = max(math.hypot(s.v_n, s.v_e), 1.0)
        l1 = k.l1_period_s * k.l1_damping * vg / math.pi
        a_lat = self._lateral(s, l1)
        bank = _clip(math.atan(a_lat / g), -k.max_bank_rad, k.max_bank_rad)
        step = k.max_roll_rate_rad_s * dt
        self.roll_cmd = _clip(bank, self.roll_cmd - step, self.roll_cmd + step)

        # --- TECS
        v = max(s.airspeed_m_s, 0.5 * trim.airspeed_m_s)
        h = -s.down_m
        hdot = -s.v_d
        vdot = (s.a_n * s.v_n + s.a_e * s.v_e + s.a_d * s.v_d) / max(math.sqrt(s.v_n**2 + s.v_e**2 + s.v_d**2), 1.0)
        h_dem = self.height_demand_m + self.height_offset_m
        hdot_dem = _clip(k.height_gain_per_s * (h_dem - h), -k.max_sink_m_s, k.max_climb_m_s)
        vdot_dem = _clip(
            k.speed_gain_per_s * (self.airspeed_demand_m_s - s.airspeed_m_s), -k.max_accel_m_s2, k.max_accel_m_s2
        )
        ste_dem, ste = hdot_dem + v * vdot_dem / g, hdot + v * vdot / g
        seb_dem, seb = hdot_dem - v * vdot_dem / g, hdot - v * vdot / g
        thr_unsat = trim.throttle + self._throttle_per_ste * ste_dem + k.throttle_p * (ste_dem - ste) + self._i_thr
        thr = _clip(thr_unsat, 0.0, 1.0)
        if thr == thr_unsat or (thr_unsat > 1.0) != (ste_dem > ste):  # anti-windup: integrate only away from a stop
            self._i_thr = _clip(self._i_thr + k.throttle_i * (ste_dem - ste) * dt, -0.5, 0.5)
        pitch_unsat = trim.alpha_rad + seb_dem / v + k.pitch_energy_p * (seb_dem - seb) / v + self._i_pitch
        self.pitch_cmd = _clip(pitch_unsat, k.min_pitch_rad, k.max_pitch_rad)
        if self.pitch_cmd == pitch_unsat:
            self._i_pitch = _clip(self._i_pitch + k.pitch_energy_i * (seb_dem - seb) / v * dt, -0.3, 0.3)

        # --- attitude loops (surface gains scale with the dynamic pressure)
        sc = (trim.airspeed_m_s / v) ** 2
        e_roll = self.roll_cmd - s.roll
        self._i_roll = _clip(self._i_roll + k.roll_i * e_roll * dt, -0.1, 0.1)
        aileron = trim.aileron_rad + sc * (-k.roll_p * e_roll - self._i_roll + k.roll_rate_d * s.p)
        cphi = max(math.cos(s.roll), 0.2)
        q_turn = g / v * math.sin(s.roll) ** 2 / cphi
        r_turn = g / v * math.sin(s.roll) * math.cos(s.pitch)
        e_pitch = self.pitch_cmd - s.pitch
        self._i_theta = _clip(self._i_theta + k.pitch_i * e_pitch * dt, -0.2, 0.2)
        elevator = trim.elevator_rad + sc * (-k.pitch_p * e_pitch - self._i_theta + k.pitch_rate_d * (s.q - q_turn))
        self._i_beta = _clip(self._i_beta + k.sideslip_i * s.beta_rad * dt, -0.1, 0.1)
        rudder = trim.rudder_rad + sc * (k.yaw_rate_d * (s.r - r_turn) - k.sideslip_p * s.beta_rad - self._i_beta)
        return aileron, elevator, thr, rudder
