"""The force-feedback law (models/force_feedback.py), pure: arrays in, corrections out."""

from __future__ import annotations

import numpy as np
import pytest

from models.errors import GainsError
from models.force_feedback import FeedbackGains, ForceFeedbackLaw, node_joints
from models.kinematics import forward_kinematics

AXES = tuple("pitch" if i % 2 == 0 else "yaw" for i in range(12))
DT = 0.02


def _law(**gains) -> ForceFeedbackLaw:
    return ForceFeedbackLaw(AXES, FeedbackGains(**gains))


def _loads(node_loads: dict[int, float]) -> np.ndarray:
    """Bottom forces per segment putting ``load`` on node ``p`` (half on each of its two segments)."""
    bottom = np.full(12, 1.0)  # 2 N on every node: under the target (5 or 8 N) unless set
    for p, load in node_loads.items():
        bottom[p - 1] = bottom[p] = load / 2
    return bottom


def test_the_nodes_are_the_inner_pitch_joints():
    assert list(node_joints(AXES)) == [2, 4, 6, 8]


def test_the_dent_presses_one_node_down_and_leaves_the_rest_of_the_body_where_it_was():
    law = _law()
    law.delta_rad[:] = [0.0, 0.02, 0.0, 0.0]  # node at joint 4
    correction = law.correction()
    assert correction[[2, 4, 6]] == pytest.approx([-0.02, 0.04, -0.02])
    assert np.count_nonzero(correction) == 3
    base = np.zeros(12)
    before = forward_kinematics(base, AXES, 0.08).points_m
    after = forward_kinematics(base + correction, AXES, 0.08).points_m
    drop = before[:, 2] - after[:, 2]
    assert drop[4] == pytest.approx(2 * 0.08 * 0.02, rel=0.01)  # the node (front of segment 5) goes down 2Lδ
    assert np.abs(drop[:3]).max() < 1e-12  # in front: untouched
    assert np.abs(after[6:] - before[6:]).max() < 2e-4  # behind the next pitch joint but one: back in place


def test_a_node_that_lost_contact_reaches_down_for_it_at_the_conform_rate_then_relaxes():
    law = _law(conform_gain=0.1)
    law.step(DT, _loads({6: 4.0}), np.ones(12, bool))  # in contact
    for _ in range(25):  # 0.5 s without contact
        law.step(DT, _loads({6: 0.0}), np.ones(12, bool))
    k = list(law.nodes).index(6)
    assert law.delta_rad[k] == pytest.approx(0.1 * 0.5, rel=0.05)
    for _ in range(500):  # 10 s: past memory_s (3 s) it stops reaching and relaxes back to the feedforward
        law.step(DT, _loads({6: 0.0}), np.ones(12, bool))
    assert abs(law.delta_rad[k]) < 0.01


def test_under_target_it_pushes_overloaded_it_yields_at_target_it_relaxes():
    law = _law(target_n=5.0, push_gain=0.1)
    for _ in range(10):
        law.step(DT, _loads({2: 2.5, 4: 25.0, 6: 8.0, 8: 8.0}), np.ones(12, bool))
    delta = dict(zip(law.nodes, law.delta_rad))
    assert delta[2] > 0  # 2.5 N < 5 N target: press
    assert delta[4] < 0  # 25 N > 20 N: yield
    assert delta[6] == 0  # between target and overload: nothing to do
    pushed = delta[2]
    for _ in range(400):
        law.step(DT, _loads({2: 6.0, 4: 8.0, 6: 8.0, 8: 8.0}), np.ones(12, bool))
    assert abs(law.delta_rad).max() < 0.02 * pushed + 1e-6  # back to the feedforward


def test_stale_or_flagged_sensors_never_drive_a_correction_and_say_why():
    law = _law()
    valid = np.ones(12, bool)
    valid[5] = False
    why = [""] * 12
    why[5] = "S06B: no estimate for 0.15 s"
    for _ in range(50):
        law.step(DT, _loads({6: 0.0, 4: 2.5}), valid, why)
    delta = dict(zip(law.nodes, law.delta_rad))
    assert delta[6] == 0.0  # node 6 = segments 5 and 6: segment 5 invalid
    assert law.fallback == {6: "S06B: no estimate for 0.15 s"}
    assert np.isnan(law.node_load_n[list(law.nodes).index(6)])
    assert delta[4] > 0  # node 4 (segments 3, 4) still feeds back


def test_rates_and_sizes_are_limited():
    law = _law(push_gain=0.5, max_rate_rad_s=0.05, max_node_rad=0.1, max_correction_rad=0.15)
    loads = _loads({2: 8.0, 4: 0.6, 6: 8.0, 8: 8.0})  # only node 4 under its target
    law.step(1.0, loads, np.ones(12, bool))
    assert law.delta_rad.max() == pytest.approx(0.05)
    for _ in range(100):
        law.step(DT * 10, loads, np.ones(12, bool))
    assert law.delta_rad.max() == pytest.approx(0.1)
    assert np.abs(law.correction()).max() == pytest.approx(0.15)  # 2δ = 0.2 at joint 4, clipped


@pytest.mark.parametrize(("values", "words"), [
    ({"push_gain": 2.0}, "'push_gain' = 2 is outside its safe range"),
    ({"target_n": 0.2, "contact_n": 0.5}, "'target_n' = 0.2 is outside"),
    ({"contact_n": 3.0, "target_n": 2.0}, "need contact_n < target_n < overload_n"),
    ({"pushgain": 0.1}, "unknown gain 'pushgain'"),
    ({"push_gain": "high"}, "'push_gain' must be a number"),
])
def test_gains_outside_their_safe_ranges_are_refused_by_name(values, words):
    with pytest.raises(GainsError, match=words.replace("(", r"\(").replace("[", r"\[")):
        FeedbackGains.from_mapping(values, "g.toml")


def _front(load_n: float) -> np.ndarray:
    """Bottom forces with ``load_n`` on the two segments ahead of the first body pitch joint (joint 3), 2 N per node
    elsewhere."""
    bottom = np.full(12, 1.0)
    bottom[[0, 1]] = load_n / 2
    return bottom


def test_the_lead_bends_while_the_front_feels_nothing_then_holds_and_yields_to_an_overload():
    law = _law(lead_gain=0.2, target_n=5.0, push_gain=0.0, conform_gain=0.0)  # the lead alone
    for _ in range(50):  # 1 s with the front in the air
        law.step(DT, _front(0.0), np.ones(12, bool))
    assert law.lead_rad == pytest.approx(0.2, rel=0.02)
    assert law.correction()[2] == pytest.approx(law.lead_rad)  # at joint 3 (what that does to the front: next test)
    held = law.lead_rad
    for _ in range(50):  # in contact, under the target: it keeps the bend that found the terrain
        law.step(DT, _front(3.0), np.ones(12, bool))
    assert law.lead_rad == pytest.approx(held)
    for _ in range(50):  # twice the target: lifts back at up to lead_gain
        law.step(DT, _front(10.0), np.ones(12, bool))
    assert law.lead_rad == pytest.approx(held - 0.2, abs=0.01)
    off = _law(push_gain=0.0, conform_gain=0.0, lead_gain=0.0)  # lead_gain 0: no lead at all
    for _ in range(50):
        off.step(DT, _front(0.0), np.ones(12, bool))
    assert off.lead_rad == 0.0 and off.correction()[2] == 0.0


@pytest.mark.parametrize("gain", [0.2, -0.2])
def test_a_positive_lead_turns_the_front_up_out_of_the_drape_a_negative_one_down(gain):
    """What the lead does to the body: with the segments behind the lead joint held where they are (they carry the
    weight; the two front segments are the light end), the head tip goes *up* under a positive lead (a positive
    pitch lifts what is behind the joint) and down under a negative one. So the default (positive) lead does not
    tilt the front down; it does the opposite, and that is the variant that traverses
    (docs/decisions/0018). Checked on the body straight and on the paper obstacle's drape."""
    for pitch in (0.0, -0.5):
        pose = np.zeros(12)
        pose[[2, 4, 6, 8]] = pitch
        law = _law(lead_gain=gain, push_gain=0.0, conform_gain=0.0)
        for _ in range(50):  # 1 s with nothing under the front
            law.step(DT, _front(0.0), np.ones(12, bool))

        def head_seen_from_joint3(angles: np.ndarray) -> np.ndarray:
            body = forward_kinematics(angles, AXES, 0.08)
            return body.frames[2].T @ (body.points_m[0] - body.points_m[2])  # in segment 3's frame

        rise = head_seen_from_joint3(pose + law.correction())[2] - head_seen_from_joint3(pose)[2]
        assert np.sign(rise) == np.sign(gain)
        turned = pitch + law.correction()[2]  # joint 3 turns the two front segments (0.16 m) by the correction
        assert abs(rise) == pytest.approx(0.16 * abs(np.sin(turned) - np.sin(pitch)), rel=1e-6)


@pytest.mark.parametrize("keep", [1.0, 0.75, 0.0])
def test_the_lead_bend_travels_back_one_pitch_joint_per_shift_fading_and_restarts_with_a_new_play(keep):
    law = _law(lead_gain=0.2, push_gain=0.0, conform_gain=0.0, lead_keep=keep)
    phases = np.arange(0, 151) * 0.02  # three shifts in 3 s
    history = []
    for k, phase in enumerate(phases):
        law.step(DT, _front(0.0 if k < 25 else 3.0), np.ones(12, bool), phase=float(phase))
        history.append(law.lead_rad)
    correction = law.correction()
    # at phase 3.0 joint 5 carries the lead's bend of phase 2.0, joint 7 of phase 1.0, joint 9 of phase 0.0, each
    # times lead_keep per pitch joint travelled
    assert correction[2] == pytest.approx(history[-1])
    for joint, behind in ((4, 1), (6, 2), (8, 3)):
        assert correction[joint] == pytest.approx(keep**behind * np.interp(3.0 - behind, phases, history))
    assert correction[10] == 0.0  # nothing yet reached joint 11 (it would be the lead's bend before the play)
    assert correction[8] == pytest.approx(keep**3 * 0.2 * DT)  # at phase 0 the front had tilted for one tick
    if keep > 0:
        assert correction[4] >= 0.07  # the bend found at the front (0.1 rad) does travel back
    law.step(DT, _front(3.0), np.ones(12, bool), phase=0.0)  # a new play: the shape re-formed at the head
    assert law.correction()[[4, 6, 8]] == pytest.approx([0.0, 0.0, 0.0])


@pytest.mark.parametrize("reach", [0, 1, 2, 12])
def test_the_lead_bend_travels_back_only_as_far_as_its_reach(reach):
    phases = np.arange(0, 251) * 0.02  # five shifts in 5 s: without a limit the bend reaches joint 11
    laws = [_law(lead_gain=0.2, push_gain=0.0, conform_gain=0.0, lead_reach=r) for r in (12, reach)]
    for k, phase in enumerate(phases):
        for law in laws:
            law.step(DT, _front(0.0 if k < 25 else 3.0), np.ones(12, bool), phase=float(phase))
    full, limited = (law.correction() for law in laws)
    assert (full[[4, 6, 8, 10]] > 0.01).all()
    for joint, behind in ((4, 1), (6, 2), (8, 3), (10, 4)):
        assert limited[joint] == (full[joint] if behind <= reach else 0.0)
    assert limited[2] == full[2]  # the lead itself is unchanged


def test_the_lead_never_acts_on_stale_or_flagged_front_sensors():
    law = _law(lead_gain=0.2, relax_s=0.5)
    for _ in range(50):
        law.step(DT, _front(0.0), np.ones(12, bool))
    valid = np.ones(12, bool)
    valid[1] = False  # S02B flagged
    before = law.lead_rad
    for _ in range(100):  # 2 s = 4 relax times: back toward the feedforward, never further down
        law.step(DT, _front(0.0), valid)
    assert law.lead_rad < before * 0.05


def test_the_lead_history_stays_bounded_however_long_the_play():
    law = _law(lead_gain=0.2, push_gain=0.0, conform_gain=0.0, lead_keep=1.0)
    for k in range(15_000):  # 5 min at 50 Hz, a shift every 10 s: 30 shifts, the history's bound 4 times over
        law.step(DT, _front(0.0 if (k // 700) % 2 else 3.0), np.ones(12, bool), phase=k * 0.002)
    assert len(law._lead_phase) <= (6 + 2) / 0.002  # the last few shifts' ticks, not the whole play's 15 000
    phases = np.asarray(law._lead_phase)
    assert phases[-1] == pytest.approx(14_999 * 0.002) and phases[0] >= phases[-1] - 8
    # what the joints behind read is still the lead's bend one, two, … shifts ago
    assert law.correction()[4] == pytest.approx(np.interp(law._phase - 1, phases, law._lead_value))


def test_the_tail_guard_closes_the_lead_while_the_tail_is_off_the_floor_and_0_turns_it_off():
    def run(guard: float, tail_n: float, ticks: int = 100) -> ForceFeedbackLaw:
        law = _law(lead_gain=0.2, push_gain=0.0, conform_gain=0.0, tail_guard_n=guard)
        for _ in range(50):  # 1 s with nothing under the front: the lead opens to 0.2 rad
            law.step(DT, _front(0.0), np.ones(12, bool))
        bottom = _front(0.0)
        bottom[[10, 11]] = tail_n / 2
        for _ in range(ticks):
            law.step(DT, bottom, np.ones(12, bool))
        return law

    assert FeedbackGains().tail_guard_n == 0.5  # on by default (docs/decisions/0019)
    assert run(0.0, 0.0, ticks=25).lead_rad == pytest.approx(0.3)  # off: the front feels nothing, the lead opens
    assert run(0.5, 2.0, ticks=25).lead_rad == pytest.approx(0.3)  # the tail on the floor: no guard
    lifted = run(0.5, 0.2, ticks=25)  # the tail carries 0.2 N < 0.5 N: the lead closes at its gain's rate
    assert lifted.lead_rad == pytest.approx(0.2 - 25 * 0.2 * DT)
    assert lifted.tail_load_n == pytest.approx(0.2)
    assert run(0.5, 0.2, ticks=200).lead_rad == 0.0  # and stops at the taught shape, never past it
    again = run(0.5, 0.2, ticks=1)
    again.step(0.0, _front(0.0) * np.r_[np.ones(10), 0.1, 0.1], np.ones(12, bool))  # a tick of no time: no change
    assert again.lead_rad == pytest.approx(0.2 - 0.2 * DT)
    valid = np.ones(12, bool)
    valid[11] = False  # a flagged tail sensor never drives the guard: the lead goes on as without it
    law = _law(lead_gain=0.2, push_gain=0.0, conform_gain=0.0, tail_guard_n=0.5)
    for _ in range(50):
        law.step(DT, _front(0.0), valid)
    assert law.lead_rad == pytest.approx(0.2) and np.isnan(law.tail_load_n)


def test_the_guard_reaching_back_closes_the_bend_already_carried_toward_the_lifted_tail():
    def run(back: float, tail_n: float, lifted_ticks: int) -> ForceFeedbackLaw:
        law = _law(lead_gain=0.1, push_gain=0.0, conform_gain=0.0, tail_guard_n=0.5, tail_guard_back=back)
        phase = 0.0
        for _ in range(200):  # 4 s with nothing under the front, the shape shifting 0.5 pitch joints a second
            phase += 0.5 * DT
            law.step(DT, _front(0.0), np.ones(12, bool), phase=phase)
        bottom = _front(0.0)
        bottom[[10, 11]] = tail_n / 2
        for _ in range(lifted_ticks):
            phase += 0.5 * DT
            law.step(DT, bottom, np.ones(12, bool), phase=phase)
        return law

    carried = run(0.0, 2.0, 0).lead_correction()
    assert carried[4] > 0.1  # the lead's bend travels back behind joint 3
    assert FeedbackGains().tail_guard_back == 0.3  # on by default (docs/decisions/0019; 0: only the lead joint closes)
    without = run(0.0, 0.2, 50).lead_correction()
    with_back = run(1.0, 0.2, 50).lead_correction()
    assert with_back[2] == pytest.approx(without[2])  # the lead joint closes as before
    behind = [4, 6, 8, 10]
    assert np.all(with_back[behind] <= without[behind] + 1e-12) and with_back[behind].sum() < without[behind].sum() - 0.1
    assert np.all(run(3.0, 0.2, 300).lead_correction() >= 0.0)  # closed toward the taught shape, never past it
    assert np.allclose(run(3.0, 2.0, 50).lead_correction(), run(0.0, 2.0, 50).lead_correction())  # tail down: none
    with pytest.raises(GainsError):
        FeedbackGains(tail_guard_back=4.0)


def test_the_default_target_and_push_are_the_crest_screens_choice():
    # 8 N and 0.2 rad/s: docs/decisions/0021
    defaults = FeedbackGains()
    assert (defaults.target_n, defaults.push_gain) == (8.0, 0.2)
    law = ForceFeedbackLaw(AXES)
    for _ in range(10):  # a node carrying 6 N, its two segments' weight and more, still presses toward 8 N
        law.step(DT, _loads({4: 6.0}), np.ones(12, bool))
    assert dict(zip(law.nodes, law.delta_rad))[4] > 0
