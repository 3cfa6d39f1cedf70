"""bench/bench_lab.py: pairing the wire's and the twin's slots, and the wall time per grasp."""

import numpy as np

from bench import bench_lab


def _trial(rank: int, success: bool, shift: float | None = 0.0, turn: float = 0.0, method: str = "seggrasp") -> dict:
    """A trial of mug_classic's handle at `rank`; `shift` (m along x) and `turn` (rad about z) move its grasp, None
    gives it none."""
    grasp = None
    if shift is not None:
        T = np.eye(4)
        T[:2, :2] = [[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]]
        T[0, 3] = 0.5 + shift
        grasp = T.tolist()
    return {"object_id": "mug_classic", "seed": 0, "method": method, "prompt": "handle", "rank": rank,
            "success": success, "T_world_grasp": grasp}


def test_slots_pair_by_key_and_grasps_match_within_the_tolerances():
    wire = [_trial(0, True), _trial(1, False), _trial(2, True, shift=0.02), _trial(3, False, shift=None),
            _trial(4, False, shift=None), _trial(5, True, turn=0.3), _trial(6, True)]
    twin = [_trial(0, True, shift=0.004), _trial(1, True, turn=0.05), _trial(2, True), _trial(3, True),
            _trial(4, False, shift=None), _trial(5, True), _trial(6, True, method="oracle")]
    counts = bench_lab.compare_slots(wire, twin)
    assert counts == {"same grasp, same result": 1, "same grasp, other result": 1, "another grasp": 2,
                      "a grasp on one side only": 1, "no grasp on either side": 1, "recorded on the wire only": 1,
                      "recorded on the twin only": 1}


def test_per_grasp_time_is_an_execution_and_the_reset_before_it():
    report = {"seconds": {"execute": [10.0, 14.0], "reset": [3.0, 5.0, 4.0]}}
    assert bench_lab._per_grasp(report) == 16.0
    assert bench_lab._per_grasp({"seconds": {"execute": [2.0], "reset": []}}) == 2.0
