"""Force-feedback body bending: corrections to the pitch goals of a propagated shape from the bottom-sheet forces.

The paper's next step (Sec. V): adjust body bending from the estimated contact forces "to better conform to and push
against complex 3-D terrain". Feedforward follow-the-leader (SPEC §5) propagates a fixed vertical-bending shape; it
pushes well while the shape matches the terrain and loses propulsion (or overloads its motors) when contact is lost
or the terrain differs (Fu & Li 2023, Bioinspir. Biomim. 18:056002). This law adds to the feedforward pitch goals a
correction that regulates the load at each *node* of the body.

Nodes. A pitch joint ``p`` (0-based, not the first and not the last pitch joint) is a node: the point of the body
where segment ``p − 1`` ends and segment ``p`` begins. Its load is the sum of the bottom-sheet forces of those two
segments (N). A correction ``δ_p`` (rad, positive = press the node down) is applied as a local dent of the pitch
angles, the discrete second difference of a bump::

    Δθ_{p−2} −= δ_p,   Δθ_p += 2 δ_p,   Δθ_{p+2} −= δ_p

(positive pitch lifts what is behind a joint; with segment length L, for small angles this lowers the node by
``2 L δ_p`` and leaves the pose of every segment beyond the two pitch joints on either side unchanged, so a node is
pressed without lifting the rest of the body off its contacts). Kano & Ishiguro's decentralised tactile control
acts locally in the same way; here the locality is exact in the kinematics, not only in the sensing.

Which nodes push. A bottom contact pushes the body along the terrain's normal there: forward where the body lies
on a slope going down toward the head (the far face of a bump), backward on a slope rising toward it. Only nodes
whose normal leans forward by more than ``slope_min`` (:meth:`ForceFeedbackLaw.node_lean`, from the joint angles
alone, taking the chord from head to tail as level) press or reach for contact; elsewhere the law only yields to an
overload. Measured without that rule: reaching for every lost contact fights the propagation itself (the head's
node reached for the top it was leaving and the body advanced 6 cm instead of 48) — Fu & Li's "excessive conforming
interrupts propagation"; and pressing nodes on the near face pushes the body back.

Law, per node and control tick of ``dt`` seconds, with the node's load ``F`` against ``target_n`` (the load a node
should push with), ``contact_n`` (below: no contact) and ``overload_n`` (above: too much)::

    overloaded (F > overload_n)              δ̇ = −conform_gain · (F − overload_n) / target_n   (yield: conform)
    pushing node, lost contact (F <         δ̇ = +conform_gain                                  (reach down: conform)
        contact_n), in contact within memory_s
    pushing node in contact, F < target_n    δ̇ = +push_gain · (target_n − F) / target_n       (press: push)
    otherwise (at target, or no sensing)     δ̇ = −δ / relax_s                                  (back to feedforward)

The lead (``lead_gain`` ≠ 0): the first body pitch joint (joint 3, behind the two front segments) bends by λ at
``lead_gain`` while their bottom sheets carry less than ``contact_n``, keeps the bend once they touch, and bends back
(up to ``lead_gain``) when they carry more than ``target_n``. λ is a pitch angle, and a positive pitch lifts what is
behind a joint: with the heavy body resting behind joint 3, a positive lead turns the light front *up and forward*,
out of a drape's downward bend (on the paper obstacle's drape +0.3 rad moves the head 2 cm up and 4 cm forward over
the far face; tests/app/test_feedback_physics.py); a negative one turns it down toward the terrain. The default is
positive; the negative lead, which tilts the front down, measured worse (it lost the paper obstacle at 0 and 0.5 N and traversed nothing
feedforward fails: docs/decisions/0018). As follow-the-leader propagates the shape one pitch joint per shift, the lead's bend travels back
with it: the pitch joint ``b`` places behind joint 3 gets the bend the lead had ``b`` shifts earlier (the shift phase
comes from the feedforward's progress; a new play starts afresh), so the propagated drape opens where the front found
nothing; ``lead_reach`` (pitch joints, default all) stops it that many pitch joints behind joint 3. Stale or flagged
front sensors: the lead relaxes to 0. The tail guard (``tail_guard_n`` > 0): while the two tail segments' bottom
sheets carry less than it (the tail has left the floor: the body balances on the terrain with both ends up, and
opening the drape further tips it off the crest), the lead closes at ``lead_gain``'s rate toward 0 instead (never past
it), and with ``tail_guard_back`` > 0 the bend it opened earlier, carried back toward the lifted tail, closes too (at
that part of the lead's rate; default 0.3, which stops the body being lifted off the crest by its own tail and
sliding back under heavy tail loads); flagged or stale tail sensors leave the lead as without the guard. How the
guard and its reaching back were chosen: docs/decisions/0019.

``|δ̇| ≤ max_rate_rad_s`` and ``|δ| ≤ max_node_rad`` (the lead too); the summed correction of each joint is clipped to
``max_correction_rad``. Gains are in rad/s per unit of relative force error. A node whose sensors are not valid
(stale, flagged by the health monitor, uncalibrated) never drives a correction: its δ relaxes to 0 (the feedforward)
and :attr:`ForceFeedbackLaw.fallback` says which nodes and why. Liljebäck's jam resolution (measured contact forces
decide where to adjust the shape) and Fu & Li's contact feedback (regain lost contact; one gain trading conforming
against pushing) are the ideas taken; the node dent is ours.

Pure numpy: arrays in, corrections out, units in the names, no clock, no I/O. One thread (the control loop's).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from models.errors import GainsError
from models.kinematics import forward_kinematics


@dataclass(frozen=True)
class FeedbackGains:
    """The law's parameters (see the module docstring); forces in N, angles in rad, times in s."""

    conform_gain: float = 0.15  # rad/s: how fast a node reaches for lost contact, and yields per unit of overload
    push_gain: float = 0.20  # rad/s per unit of relative force deficit
    target_n: float = 8.0  # the load a node in contact should push with (two segments weigh ~3.9 N); 8 N and push
    # 0.2: docs/decisions/0021 (a gains file or the Gait tab sets them)
    contact_n: float = 0.5  # below this a node has no contact
    overload_n: float = 20.0  # above this a node is overloaded (its servos near their stall torque)
    memory_s: float = 3.0  # a node that had contact this recently and lost it reaches for it again
    relax_s: float = 1.0  # time constant back to the feedforward
    slope_min: float = 0.15  # a node pushes where its contact normal leans forward by more than this (sine)
    relieve_gain: float = 0.0  # rad/s per unit of relative load: lift nodes on the near face (leaning back)
    lead_gain: float = 0.1  # rad/s, signed: + the front straightens out (turns up) while it feels nothing, − it tilts down
    lead_keep: float = 1.0  # the part of the lead's bend kept per pitch joint it travels back (1: all of it)
    lead_reach: float = 12.0  # how many pitch joints behind the lead its bend travels (12: all; 0: it stays at the lead)
    tail_guard_n: float = 0.5  # N: while the two tail segments carry less, the lead closes instead of opening (0: off)
    tail_guard_back: float = 0.3  # while the guard acts, the bend already carried back closes too, at this part of the
    # lead's rate (0: only the lead joint closes). 0.3: docs/decisions/0019
    max_rate_rad_s: float = 0.2
    max_node_rad: float = 0.35
    max_correction_rad: float = 0.5

    def __post_init__(self) -> None:
        check_gains(self)

    @classmethod
    def from_mapping(cls, values: dict, source: str = "gains") -> FeedbackGains:
        known = {f.name for f in fields(cls)}
        for key in values:
            if key not in known:
                raise GainsError(f"{source}: unknown gain '{key}' (known: {', '.join(sorted(known))})")
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise GainsError(f"{source}: '{key}' must be a number, got {value!r}")
        try:
            return cls(**{k: float(v) for k, v in values.items()})
        except GainsError as exc:
            raise GainsError(f"{source}: {exc}") from None


# The safe range of every gain: what the GUI's live adjustment and a gains file may set.
GAIN_RANGES: dict[str, tuple[float, float]] = {
    "conform_gain": (0.0, 0.5), "push_gain": (0.0, 0.5), "target_n": (0.5, 20.0), "contact_n": (0.05, 5.0),
    "overload_n": (1.0, 40.0), "memory_s": (0.0, 30.0), "relax_s": (0.05, 30.0), "max_rate_rad_s": (0.0, 1.0),
    "max_node_rad": (0.0, 0.6), "max_correction_rad": (0.0, 0.8), "slope_min": (-1.0, 1.0), "relieve_gain": (0.0, 0.5),
    "lead_gain": (-0.5, 0.5), "lead_keep": (0.0, 1.0), "lead_reach": (0.0, 12.0), "tail_guard_n": (0.0, 5.0),
    "tail_guard_back": (0.0, 3.0),
}


def check_gains(gains: FeedbackGains) -> None:
    for name, (low, high) in GAIN_RANGES.items():
        value = getattr(gains, name)
        if not (math.isfinite(value) and low <= value <= high):
            raise GainsError(f"'{name}' = {value:g} is outside its safe range [{low:g}, {high:g}]")
    if not gains.contact_n < gains.target_n < gains.overload_n:
        raise GainsError(f"need contact_n < target_n < overload_n, got {gains.contact_n:g}, {gains.target_n:g}, "
                         f"{gains.overload_n:g} N")


def node_joints(axes: Sequence[str]) -> np.ndarray:
    """The pitch joints that are nodes: every pitch joint with a pitch joint before and after it."""
    pitch = [j for j, axis in enumerate(axes) if axis == "pitch"]
    return np.array(pitch[1:-1], dtype=int)


class ForceFeedbackLaw:
    """The law with its state (each node's δ and when it last had contact). ``step`` once per control tick."""

    def __init__(self, axes: Sequence[str], gains: FeedbackGains | None = None) -> None:
        self.axes = tuple(axes)
        self.gains = gains or FeedbackGains()
        pitch = [j for j, axis in enumerate(self.axes) if axis == "pitch"]
        self.nodes = node_joints(self.axes)
        # the pitch joints before and after each node, and the two segments meeting at it
        self._before = np.array([pitch[pitch.index(p) - 1] for p in self.nodes], dtype=int)
        self._after = np.array([pitch[pitch.index(p) + 1] for p in self.nodes], dtype=int)
        self._segments = np.stack([self.nodes - 1, self.nodes], axis=1)
        self.delta_rad = np.zeros(len(self.nodes))
        self._last_contact_s = np.full(len(self.nodes), -math.inf)
        self._t_s = 0.0
        self.fallback: dict[int, str] = {}  # node joint → why it is on feedforward now
        self.node_load_n = np.full(len(self.nodes), np.nan)
        self.pushing = np.zeros(len(self.nodes), bool)  # the nodes the feedforward bends down around (may push)
        # the lead: the first pitch joint behind the front (it turns the segments ahead of it), their segments, and
        # the pitch joints behind it in order (where its bend travels as the shape propagates)
        self._pitch = np.array(pitch, dtype=int)
        self._lead_joint = int(pitch[1]) if len(pitch) > 1 else -1
        self._lead_segments = np.arange(0, max(self._lead_joint, 0))
        self.lead_rad = 0.0
        self.front_load_n = math.nan  # the load the lead last acted on (N; NaN: off or not sensed)
        self._tail_segments = np.arange(max(len(self.axes) - 2, 0), len(self.axes))
        self.tail_load_n = math.nan  # the tail's load the guard last read (N; NaN: guard off or not sensed)
        self._lead_phase: list[float] = []
        self._lead_value: list[float] = []
        self._phase = 0.0

    def set_gains(self, gains: FeedbackGains) -> None:
        """New gains from the next tick on (live adjustment); the state carries over."""
        check_gains(gains)
        self.gains = gains

    def reset(self) -> None:
        self.delta_rad[:] = 0.0
        self._last_contact_s[:] = -math.inf
        self._t_s = 0.0
        self.fallback = {}
        self.lead_rad = 0.0
        self._lead_phase, self._lead_value = [], []
        self._phase = 0.0

    def node_loads(self, bottom_n: np.ndarray) -> np.ndarray:
        """Each node's load (N): the bottom forces of the two segments meeting at it."""
        return np.asarray(bottom_n, dtype=float)[self._segments].sum(axis=1)

    def node_lean(self, angles_rad: np.ndarray, segment_length_m: float = 0.08) -> np.ndarray:
        """Per node, the forward lean (sine) of the body's outward bottom normal there, in the frame where the chord
        from the head tip to the tail end is level: > 0 where the node lies on a slope going down toward the head
        (pressing there pushes the body forward), < 0 on a slope rising toward the head (pressing there pushes it
        back). From the joint angles alone (forward kinematics); assumes head and tail rest at one height."""
        pose = forward_kinematics(np.asarray(angles_rad, dtype=float), self.axes, segment_length_m)
        chord = pose.points_m[-1] - pose.points_m[0]  # points backward along the body
        level = math.atan2(chord[2], -chord[0])  # how far the chord dips below the head frame's −x
        up = pose.frames[:, :, 2]  # each segment's up axis (its bottom sheet's inward normal)
        normal = 0.5 * (up[self.nodes - 1] + up[self.nodes])
        # rotate about y by the chord's dip so that the chord is level; x of the rotated normal = its forward lean
        c, s = math.cos(level), math.sin(level)
        lean = c * normal[:, 0] - s * normal[:, 2]
        return lean / np.maximum(np.linalg.norm(normal, axis=1), 1e-9)

    def step(self, dt_s: float, bottom_n: np.ndarray, valid: np.ndarray, why_invalid: Sequence[str] = (),
             present_rad: np.ndarray | None = None, phase: float | None = None) -> np.ndarray:
        """One tick: ``bottom_n`` (n segments) the estimated bottom-sheet forces, ``valid`` (n) which may drive a
        correction (``why_invalid[s]`` says why not, for :attr:`fallback`), ``present_rad`` (n joints) the present
        joint angles (for :meth:`node_lean`; None: every node may push). Returns the correction (n joints, rad) to
        add to the feedforward goals."""
        g = self.gains
        self._t_s += dt_s
        bottom = np.asarray(bottom_n, dtype=float)
        ok = np.asarray(valid, dtype=bool)[self._segments].all(axis=1) & np.isfinite(bottom[self._segments]).all(axis=1)
        load = np.where(ok, np.nan_to_num(bottom)[self._segments].sum(axis=1), np.nan)
        self.node_load_n = load
        rate = -self.delta_rad / g.relax_s
        in_contact = ok & (load >= g.contact_n)
        self._last_contact_s[in_contact] = self._t_s
        over = ok & (load > g.overload_n)
        lean = np.zeros(len(self.nodes)) if present_rad is None else self.node_lean(present_rad)
        wraps = np.ones(len(self.nodes), bool) if present_rad is None else lean > g.slope_min
        braking = np.zeros(len(self.nodes), bool) if present_rad is None else lean < -g.slope_min
        self.pushing = wraps
        lost = ok & wraps & ~in_contact & (self._t_s - self._last_contact_s <= g.memory_s)
        under = wraps & in_contact & (load < g.target_n)
        rate = np.where(over, -g.conform_gain * (np.nan_to_num(load) - g.overload_n) / g.target_n, rate)
        rate = np.where(lost, g.conform_gain, rate)
        rate = np.where(under, g.push_gain * (g.target_n - np.nan_to_num(load)) / g.target_n, rate)
        # a node on the near face pushes the body back: lift it off in proportion to its load (relieve_gain 0: off)
        relieve = braking & in_contact & ~over
        rate = np.where(relieve, -g.relieve_gain * np.nan_to_num(load) / g.target_n, rate)
        rate = np.clip(rate, -g.max_rate_rad_s, g.max_rate_rad_s)
        self.delta_rad = np.clip(self.delta_rad + rate * dt_s, -g.max_node_rad, g.max_node_rad)
        self._step_lead(dt_s, bottom, np.asarray(valid, dtype=bool), phase)
        self.fallback = {}
        for k in np.flatnonzero(~ok):
            reasons = [why_invalid[s] for s in self._segments[k] if s < len(why_invalid) and why_invalid[s]]
            self.fallback[int(self.nodes[k])] = "; ".join(reasons) or "no force estimate"
        return self.correction()

    def _step_lead(self, dt_s: float, bottom: np.ndarray, valid: np.ndarray, phase: float | None) -> None:
        g = self.gains
        self.front_load_n = math.nan
        if g.lead_gain == 0.0 or self._lead_joint < 0:
            self.lead_rad = 0.0
            return
        segments = self._lead_segments
        tail_off = False
        if valid[segments].all() and np.isfinite(bottom[segments]).all():
            load = self.front_load_n = float(bottom[segments].sum())
            if load < g.contact_n:
                rate = g.lead_gain  # nothing under the front: bend it (up and forward for a positive gain)
            elif load > g.target_n:
                rate = -g.lead_gain * min((load - g.target_n) / g.target_n, 1.0)
            else:
                rate = 0.0  # in contact: keep the bend that found it
            tail = self._tail_segments
            self.tail_load_n = math.nan
            if g.tail_guard_n > 0.0 and valid[tail].all() and np.isfinite(bottom[tail]).all():
                self.tail_load_n = float(bottom[tail].sum())
                tail_off = self.tail_load_n < g.tail_guard_n
                if tail_off and self.lead_rad != 0.0:
                    # the tail has left the floor: the body balances on the terrain with both ends up (a seesaw);
                    # opening the drape further tips it over the crest. Close the lead back toward the taught shape.
                    closing = abs(g.lead_gain) if dt_s <= 0.0 else min(abs(g.lead_gain), abs(self.lead_rad) / dt_s)
                    rate = -math.copysign(closing, self.lead_rad)
        else:
            rate = -self.lead_rad / g.relax_s
        self.lead_rad = float(np.clip(self.lead_rad + np.clip(rate, -g.max_rate_rad_s, g.max_rate_rad_s) * dt_s,
                                      -g.max_node_rad, g.max_node_rad))
        if tail_off and g.tail_guard_back > 0.0 and dt_s > 0.0 and self._lead_value:
            # the bend the lead opened earlier is travelling back toward the lifted tail: close it too, never past 0
            step = g.tail_guard_back * abs(g.lead_gain) * dt_s
            self._lead_value = [v - math.copysign(min(abs(v), step), v) for v in self._lead_value]
        if phase is None:
            return
        if self._lead_phase and phase < self._lead_phase[-1] - 0.5:  # a new play: the shape re-formed at the head
            self._lead_phase, self._lead_value = [], []
        if not self._lead_phase or phase > self._lead_phase[-1]:
            self._lead_phase.append(float(phase))
            self._lead_value.append(self.lead_rad)
            # only the last (pitch joints behind the lead) shifts can still be read: the history stays bounded
            # however long a play lasts (a few shifts' ticks)
            keep = bisect.bisect_left(self._lead_phase, phase - len(self._pitch) - 1)
            if keep:
                del self._lead_phase[:keep], self._lead_value[:keep]
        self._phase = float(phase)

    def lead_correction(self) -> np.ndarray:
        """The lead's bend at its joint and, carried back one pitch joint per shift, behind it (rad per joint): a
        positive pitch, which lifts what is behind the joint; with the heavy body resting behind it, that turns the
        light front up and forward, out of a drape's downward bend (see the module docstring)."""
        out = np.zeros(len(self.axes))
        if self.gains.lead_gain == 0.0 or self._lead_joint < 0:
            return out
        out[self._lead_joint] = self.lead_rad
        if self._lead_phase:
            phases = np.asarray(self._lead_phase)
            values = np.asarray(self._lead_value)
            for behind, joint in enumerate(self._pitch[2:], start=1):
                at = self._phase - behind
                if at >= phases[0] and behind <= self.gains.lead_reach:
                    out[joint] = self.gains.lead_keep ** behind * float(np.interp(at, phases, values))
        return out

    def correction(self) -> np.ndarray:
        """The present correction per joint (rad): each node's dent and the lead's propagated bend, summed and
        clipped."""
        out = self.lead_correction()
        np.add.at(out, self._before, -self.delta_rad)
        np.add.at(out, self.nodes, 2.0 * self.delta_rad)
        np.add.at(out, self._after, -self.delta_rad)
        limit = self.gains.max_correction_rad
        return np.clip(out, -limit, limit)
