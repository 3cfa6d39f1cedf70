"""The episode on the simulated cell with labelled primitives: oracle, coarse and shapegrasp episodes, the no-grasp
slot, outcome reuse, the vote cache, failure names and the table plane."""

import numpy as np
import pytest
import trimesh

from seggrasp.baselines import shapegrasp_grasps, shapegrasp_labels
from seggrasp.decompose import Partition
from seggrasp.fusion import part_mean_scores
from seggrasp.grasp import AntipodalConfig, AntipodalSampler, GraspSet, select_per_prompt
from seggrasp.hands import ROBOTIQ_2F85
from seggrasp.cell import GraspOutcome
from seggrasp.episode import (Episode, EpisodeContext, EpisodeSettings, Observation, failure_of, plan_slots,
                              table_plane_in_object_frame)
from seggrasp.labels import PartLabels, find_prompt, prompt_index
from seggrasp.method import ObjectSegmenter, PartPlan
from seggrasp.truth import DetectorSpec, GroundTruth
from sim.cell import SimCell
from sim.primitives import primitive_object

IMAGE = (160, 120)


@pytest.fixture(scope="module")
def cylinder(tmp_path_factory):
    return primitive_object("cylinder", (0.03, 0.11), tmp_path_factory.mktemp("objects"), mass=0.2)


@pytest.fixture(scope="module")
def cell(cylinder):
    with SimCell([cylinder], embodiment="floating", seed=0, image_size=IMAGE) as sim_cell:
        yield sim_cell


def run_episode(cell, model, method, detector=DetectorSpec(), targets=None, outcome_cache=None, on_record=None,
                **settings):
    """One method's episode on the twin primitive `model` (its ground truth passed in, as a harness does)."""
    context = EpisodeContext.from_object(model, scene_seed=2)
    truth = GroundTruth.of_object(model, context.prompts, true_pose=lambda: cell.object_mesh()[1])
    episode = Episode(cell, context, detector, truth, EpisodeSettings(**settings), outcome_cache=outcome_cache)
    return episode.run(method, targets, on_record=on_record)


def test_table_plane_passes_through_the_lowest_point() -> None:
    mesh = trimesh.creation.box((0.04, 0.06, 0.1))
    T = trimesh.transformations.rotation_matrix(0.4, [1, 1, 0])
    T[:3, 3] = [0.5, 0.1, 0.3]
    plane = table_plane_in_object_frame(mesh, T)
    heights = mesh.vertices @ plane[:3] + plane[3]
    world_z = (mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, 2]
    assert heights.min() == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(heights, world_z - world_z.min())


@pytest.mark.slow
def test_oracle_episode_lifts_by_the_side_and_judges_the_top_infeasible(cell, cylinder) -> None:
    records = run_episode(cell, cylinder, "oracle", targets=["side", "top"], top_k=3, seed=0)
    assert [(r.prompt, r.rank) for r in records] == [("side", 0), ("side", 1), ("side", 2), ("top", 0), ("top", 1),
                                                      ("top", 2)]
    side, top = records[:3], records[3:]
    for r in side:
        assert r.method == "oracle" and r.detector == "ground-truth"
        assert r.executed and r.contacts_on_part and r.touched_on_part
        assert r.lift_height > 0.15  # held while lifting (`lifted` also needs 18 cm: slips of ~2 cm happen)
        assert len(r.T_world_grasp) == 4 and len(r.quaternion_xyzw) == 4
    assert sum(r.success for r in side) >= 2
    assert side[0].grasp_score >= side[1].grasp_score >= side[2].grasp_score
    # both contacts of an antipodal grasp can never lie on the flat top face: judged infeasible, nothing to execute
    for r in top:
        assert not r.executed and r.n_candidates == 0 and r.success is False and r.contacts_on_part is False
        assert r.failure == "infeasible" and r.infeasible is True
        assert r.message == "top: narrowest section 110 mm, wider than the 80 mm the robotiq_2f85 closes on (85 mm " \
            "stroke less 5 mm)"
    assert all(r.infeasible is False for r in side)
    assert all(r.failure == "" for r in side if r.success)


@pytest.mark.slow
def test_outcomes_are_reused_for_identical_grasps(cell, cylinder) -> None:
    cache: dict = {}
    context = EpisodeContext.from_object(cylinder, scene_seed=2)
    truth = GroundTruth.of_object(cylinder, context.prompts)
    episode = Episode(cell, context, None, truth, EpisodeSettings(top_k=2), outcome_cache=cache)
    first = episode.run("oracle", ["side"])
    again = episode.run("oracle", ["side"])
    assert len(cache) == 2
    assert not any(r.reused_outcome for r in first) and all(r.reused_outcome for r in again)
    assert [r.lift_height for r in first] == [r.lift_height for r in again]


@pytest.mark.slow
def test_run_s_hooks_see_the_plan_then_each_slot_before_and_its_record_after(cell, cylinder) -> None:
    """The benchmark's hooks (sim/evaluate/runner.py): a skipped slot is neither announced nor executed, and
    `moves_cell` says before a slot whether its outcome will be reused."""
    cache: dict = {}
    context = EpisodeContext.from_object(cylinder, scene_seed=2)
    truth = GroundTruth.of_object(cylinder, context.prompts)
    episode = Episode(cell, context, None, truth, EpisodeSettings(top_k=2), outcome_cache=cache)
    for run in range(2):
        events: list = []
        records = episode.run("oracle", ["side"], skip=lambda slot: slot.rank == 1,
                              on_plan=lambda plan: events.append(("plan", plan.method)),
                              before=lambda slot: events.append(("before", slot.rank, episode.moves_cell(slot))),
                              on_record=lambda record: events.append(("record", record.rank, record.reused_outcome)))
        assert [r.rank for r in records] == [0]
        assert events == [("plan", "oracle"), ("before", 0, run == 0), ("record", 0, run == 1)]


@pytest.mark.slow
def test_coarse_episode_names_its_detector_and_executes_on_voted_faces(cell, cylinder) -> None:
    streamed = []
    records = run_episode(cell, cylinder, "coarse", DetectorSpec(preset="perfect"), targets=[" SIDE "], top_k=2,
                          on_record=streamed.append)
    assert streamed == records
    assert all(r.method == "coarse" and r.detector == "simulated:perfect" for r in records)
    assert all(r.executed for r in records)


def test_unknown_method_and_target_are_rejected(cell, cylinder) -> None:
    with pytest.raises(ValueError, match="unknown method"):
        run_episode(cell, cylinder, "magic")
    with pytest.raises(ValueError, match="not among the prompts"):
        run_episode(cell, cylinder, "oracle", targets=["handle"])
    unlabelled = EpisodeContext(cylinder.object_id, "cylinder", ["side"], scene_seed=2)
    with pytest.raises(ValueError, match="ground-truth"):
        Episode(cell, unlabelled, DetectorSpec()).run("oracle")


def test_shapegrasp_grasps_top_down_at_the_voted_part() -> None:
    """Two stacked boxes as two convex parts; votes for prompt 0 on the upper one, prompt 1 on the lower one."""
    lower = trimesh.creation.box((0.05, 0.05, 0.06))
    lower.apply_translation([0, 0, 0.03])
    upper = trimesh.creation.box((0.03, 0.03, 0.04))
    upper.apply_translation([0, 0, 0.08])
    mesh = trimesh.util.concatenate([lower, upper])
    part_of_face = np.r_[np.zeros(len(lower.faces), int), np.ones(len(upper.faces), int)]
    scores = np.zeros((len(mesh.faces), 2))
    scores[part_of_face == 1, 0] = 1.0
    scores[:, 1] = 0.2
    scores[part_of_face == 0, 1] = 0.9
    votes = part_mean_scores(scores, part_of_face, mesh.area_faces)
    assert np.array_equal(shapegrasp_labels(votes, part_of_face), np.where(part_of_face == 1, 0, 1))
    T_world_obj = np.eye(4)
    T_world_obj[:3, 3] = [0.5, 0.0, 0.0]
    grasps = shapegrasp_grasps(mesh, votes, part_of_face, T_world_obj)
    assert [len(g) for g in grasps] == [1, 1]
    upper_grasp = grasps[0]
    assert np.allclose(upper_grasp.poses[0, :3, 2], [0, 0, -1])  # approach straight down
    assert np.allclose(upper_grasp.poses[0, :3, 0], [1, 0, 0])  # fixed closing axis
    assert np.allclose(upper_grasp.poses[0, :2, 3], 0.0, atol=1e-9)
    assert upper_grasp.poses[0, 2, 3] == pytest.approx(0.08, abs=0.005)  # the upper part's centroid height
    assert upper_grasp.widths[0] == pytest.approx(0.03, abs=1e-6)  # fingers meet the upper box's sides
    # the lower part's centroid is too low for the fingertips: the grasp is raised above the table
    assert grasps[1].poses[0, 2, 3] >= 0.02


def cylinder_votes(cylinder):
    """Votes on the cylinder's three surfaces: the top says "top"; the side and the bottom both lean to "side", the
    bottom only slightly; and a decomposition whose parts are the three surfaces."""
    gt = cylinder.labels.face_labels
    votes = np.zeros((len(gt), 3))
    votes[gt == 0, 0] = 1.0
    votes[gt == 1, 1] = 1.0
    votes[gt == 2] = [0.0, 0.6, 0.5]
    segmenter = ObjectSegmenter(cylinder.mesh, ["top", "side", "bottom"], None, "votes", coarse_scores=votes,
                                partitions=[Partition(0.05, np.asarray(gt))])
    return gt, votes, segmenter


def test_seggrasp_agree_selects_grasps_only_where_its_labels_agree_with_the_votes(cylinder) -> None:
    gt, votes, segmenter = cylinder_votes(cylinder)
    plan = segmenter.plan("seggrasp-agree", np.eye(4))
    anchored = segmenter.plan("anchored", np.eye(4))
    np.testing.assert_array_equal(plan.labels, anchored.labels)
    assert anchored.grasp_labels is None and anchored.policy is None
    coarse = np.argmax(votes, axis=1)
    expected = np.where(plan.labels == coarse, plan.labels, -1)
    np.testing.assert_array_equal(plan.grasp_labels, expected)
    assert (plan.labels[gt == 2] == 2).all()  # anchoring gives "bottom" its own part ...
    assert (plan.grasp_labels[gt == 2] == -1).all()  # ... but the votes disagree there: no grasps on it


def test_seggrasp_fills_the_request_the_agreement_filter_leaves_empty(cylinder) -> None:
    gt, _, segmenter = cylinder_votes(cylinder)
    mesh = cylinder.mesh
    # two grasps with both contacts on the bottom disc, one on the side (better scored)
    contacts = np.array([[[-0.01, 0.0, 0.0], [0.01, 0.0, 0.0]], [[0.0, -0.01, 0.0], [0.0, 0.01, 0.0]],
                         [[-0.03, 0.0, 0.05], [0.03, 0.0, 0.05]]])
    poses = np.repeat(np.eye(4)[None], 3, axis=0)
    grasps = GraspSet(poses, [0.02, 0.02, 0.06], [0.2, 0.1, 0.9], contacts)
    observation = Observation(mesh, np.eye(4))
    plan = segmenter.plan("seggrasp", np.eye(4))
    assert plan.grasp_labels is None and plan.policy is not None
    assert plan.face_probabilities.shape == (len(gt), 3)
    np.testing.assert_allclose(plan.face_probabilities.sum(axis=1), 1.0)
    slots = plan_slots(plan, grasps, observation, 3, [2], top_k=3)
    assert [s.grasp is not None for s in slots] == [True, True, False]
    assert [float(s.grasp.scores[0]) for s in slots[:2]] == [0.2, 0.1]  # the region in the generator's order
    agree = plan_slots(segmenter.plan("seggrasp-agree", np.eye(4)), grasps, observation, 3, [2], top_k=3)
    assert all(s.grasp is None for s in agree)
    side = plan_slots(plan, grasps, observation, 3, [1], top_k=1)
    assert side[0].grasp is not None and float(side[0].grasp.scores[0]) == 0.9


def test_slots_take_the_grasps_the_arm_reaches_first_and_fill_up_with_the_others(cylinder) -> None:
    mesh = cylinder.mesh
    n = 8
    poses = np.repeat(np.eye(4)[None], n, axis=0)
    poses[:, 0, 3] = 1e-3 * np.arange(n)  # grasp i sits at x = i mm
    contacts = np.repeat(np.array([[[-0.03, 0.0, 0.05], [0.03, 0.0, 0.05]]]), n, axis=0)  # all on the side
    grasps = GraspSet(poses, np.full(n, 0.06), np.linspace(1.0, 0.3, n), contacts)
    plan = PartPlan("oracle", "ground-truth", np.asarray(cylinder.labels.face_labels))  # top, side, bottom
    observation = Observation(mesh, np.eye(4))
    asked = []

    def grasp_at(T) -> int:
        return int(round(T[0, 3] * 1e3))

    def reaches(T, width) -> bool:
        asked.append(grasp_at(T))
        return grasp_at(T) not in (0, 2)

    slots = plan_slots(plan, grasps, observation, 3, [1], top_k=3, reaches=reaches)
    assert [grasp_at(s.grasp.poses[0]) for s in slots] == [1, 3, 4]  # rank order among the reachable ones
    assert asked == [0, 1, 2, 3, 4]  # checked only until three reachable ones were found
    (top1,) = plan_slots(plan, grasps, observation, 3, [1], top_k=1, reaches=lambda T, w: grasp_at(T) == 6)
    assert grasp_at(top1.grasp.poses[0]) == 6  # a top-1 request looks further than three grasps deep
    asked.clear()
    few = plan_slots(plan, grasps, observation, 3, [1], top_k=3, reaches=lambda T, w: grasp_at(T) == 5)
    assert [grasp_at(s.grasp.poses[0]) for s in few] == [5, 0, 1]  # unreachable ones fill the slots left
    assert [grasp_at(s.grasp.poses[0]) for s in plan_slots(plan, grasps, observation, 3, [1], 3)] == [0, 1, 2]


class OutOfReachCell:
    """A cell on a fixed mesh whose arm reaches no grasp centred above `z_limit` (world = object frame); it counts
    its resets and the checks made in a scene a grasp was executed in since the last reset (`checked_disturbed`)."""

    hand = ROBOTIQ_2F85

    def __init__(self, mesh: trimesh.Trimesh, z_limit: float, models_scene: bool = True) -> None:
        self.mesh, self.z_limit, self.models_scene, self.checked = mesh, z_limit, models_scene, 0
        self.disturbed, self.checked_disturbed, self.resets = False, 0, 0

    def reset(self, seed=None, object_id=None) -> None:
        self.disturbed = False
        self.resets += 1

    def object_mesh(self):
        return self.mesh, np.eye(4)

    def check_reach(self, T_world_grasp, width) -> str:
        self.checked += 1
        self.checked_disturbed += self.disturbed
        return "unreachable: too high" if T_world_grasp[2, 3] > self.z_limit else ""

    def execute(self, T_world_grasp, width) -> GraspOutcome:
        self.disturbed = True
        refusal = self.check_reach(T_world_grasp, width)
        return GraspOutcome(False, False, 0.0, message=refusal, failure="unreachable") if refusal else \
            GraspOutcome(True, False, 0.0)


@pytest.mark.slow
def test_an_episode_asks_its_cell_which_grasps_it_can_execute_once_per_grasp_in_a_fresh_scene(cylinder) -> None:
    mesh, labels = cylinder.mesh, cylinder.labels.face_labels
    context = EpisodeContext("cylinder", "cylinder", ["top", "side", "bottom"], scene_seed=0)
    free = Episode(OutOfReachCell(mesh, np.inf), context, None, GroundTruth(mesh, labels))
    best = [s.grasp.poses[0, 2, 3] for s in free.slots(free.plan("oracle"), ["side"])]
    z_limit = float(np.median(best))  # half of the side's ten best grasps are out of reach
    cell = OutOfReachCell(mesh, z_limit)
    episode = Episode(cell, context, None, GroundTruth(mesh, labels))
    slots = episode.slots(episode.plan("oracle"), ["side"])
    assert len(slots) == 10 and all(s.grasp is not None for s in slots)
    assert all(s.grasp.poses[0, 2, 3] <= z_limit for s in slots)  # the side has lower grasps to fill all ten
    checked = cell.checked
    episode.slots(episode.plan("oracle"), ["side"])
    assert cell.checked == checked  # remembered per grasp
    assert all(episode.execute(slot).failure != "unreachable" for slot in slots[:3])
    checked, disturbed = cell.checked, cell.checked_disturbed  # execute's own check runs in the scene it moves
    episode.reaches(np.eye(4), 0.05)  # a grasp not checked before
    assert cell.checked == checked + 1 and cell.checked_disturbed == disturbed  # in the scene a slot will find


@pytest.mark.slow
@pytest.mark.parametrize("models_scene", [True, False])
def test_a_cell_that_checks_only_its_arm_is_reset_once_per_grasp(cylinder, models_scene) -> None:
    """The real cell's reset asks a person to place the object: it comes once per executed grasp, whatever is
    checked in between; the twin checks and executes from fresh resets (no outcome depends on earlier checks)."""
    mesh, labels = cylinder.mesh, cylinder.labels.face_labels
    context = EpisodeContext("cylinder", "cylinder", ["top", "side", "bottom"], scene_seed=0)
    cell = OutOfReachCell(mesh, np.inf, models_scene=models_scene)
    episode = Episode(cell, context, None, GroundTruth(mesh, labels), EpisodeSettings(top_k=2))
    records = episode.run("oracle", ["side"])  # observes, checks, executes two grasps
    episode.reaches(np.eye(4), 0.05)  # a grasp not checked before, as when the next method is planned
    records.append(episode.execute(episode.slots(episode.plan("oracle"), ["side"])[0]))
    assert [r.executed for r in records] == [True, True, True]
    if models_scene:  # observe; before each execution; before the new check
        assert cell.resets == 1 + 3 + 1
    else:  # the first grasp goes in the scene just observed, and the new check needs no scene
        assert cell.resets == 3



class CountingSampler(AntipodalSampler):
    """The antipodal sampler, counting its calls per `on_faces` given or not."""

    def __init__(self, config: AntipodalConfig) -> None:
        super().__init__(config)
        self.calls = {"everywhere": 0, "on a part": 0}

    def generate(self, *args, on_faces=None, **kwargs) -> GraspSet:
        self.calls["everywhere" if on_faces is None else "on a part"] += 1
        return super().generate(*args, on_faces=on_faces, **kwargs)


def test_a_part_too_few_candidates_hold_gets_candidates_sampled_on_it(box_with_knob) -> None:
    mesh, labels = box_with_knob
    context = EpisodeContext("box_with_knob", "box", ["body", "knob"], scene_seed=0)
    sampler = CountingSampler(AntipodalConfig(n_surface_samples=300, envelope_centres=0))
    episode = Episode(OutOfReachCell(mesh, np.inf), context, None, GroundTruth(mesh, labels), generator=sampler)
    surface = episode.footprint.on(mesh)

    def holding(grasps: GraspSet, k: int) -> int:
        return int(surface.holds(grasps.subset(select_per_prompt(grasps, mesh, labels, 2, len(grasps))[k]),
                                 labels == k).sum())

    everywhere = episode.grasps()
    assert holding(everywhere, 0) >= 10 and holding(everywhere, 1) < 10  # the knob is 3 % of the surface
    oracle = episode.plan("oracle")
    assert len(episode.planning_grasps(oracle, [0])) == len(everywhere)  # the body has enough: nothing added
    assert sampler.calls == {"everywhere": 1, "on a part": 0}
    topped_up = episode.planning_grasps(oracle, [0, 1])
    assert np.array_equal(topped_up.poses[: len(everywhere)], everywhere.poses)
    assert holding(topped_up, 1) >= 10 and holding(topped_up, 0) >= holding(everywhere, 0)
    slots = episode.slots(episode.plan("oracle"), ["knob"])
    assert len(slots) == 10 and all(s.grasp is not None and s.n_candidates == 10 for s in slots)
    assert sampler.calls == {"everywhere": 1, "on a part": 1}  # the knob's candidates are sampled once


def test_a_part_the_whole_draw_misses_is_judged_on_its_own_draw(box_with_knob) -> None:
    mesh, labels = box_with_knob
    context = EpisodeContext("box_with_knob", "box", ["body", "knob"], scene_seed=0)
    sampler = CountingSampler(AntipodalConfig(n_surface_samples=40, near_com_fraction=0.0, envelope_centres=0))
    episode = Episode(OutOfReachCell(mesh, np.inf), context, None, GroundTruth(mesh, labels), generator=sampler)
    oracle = episode.plan("oracle")
    surface = episode.footprint.on(mesh)
    everywhere = episode.grasps()
    ranked = everywhere.subset(select_per_prompt(everywhere, mesh, labels, 2, len(everywhere))[1])
    assert not surface.holds(ranked, labels == 1).any()  # 40 samples over the box: none of the knob's holds
    judged = episode.feasibility(oracle, [0, 1])
    assert judged[0].feasible and sampler.calls == {"everywhere": 1, "on a part": 1}
    assert judged[1].feasible  # the knob's own draw holds it
    slots = episode.slots(oracle, ["knob"])
    assert all(s.grasp is not None for s in slots[:3])  # and its slots are filled from that draw


def short_draw_episode(box_with_knob) -> tuple[Episode, CountingSampler]:
    """An oracle episode on the knobbed box whose draws take 20 samples: one draw on the knob leaves it short."""
    mesh, labels = box_with_knob
    context = EpisodeContext("box_with_knob", "box", ["body", "knob"], scene_seed=0)
    config = AntipodalConfig(n_surface_samples=20, part_draw_samples=1, part_draw_rounds=6, envelope_centres=0)
    sampler = CountingSampler(config)
    return Episode(OutOfReachCell(mesh, np.inf), context, None, GroundTruth(mesh, labels), generator=sampler), sampler


def test_a_part_one_draw_leaves_short_is_drawn_again_until_top_k_hold(box_with_knob) -> None:
    mesh, labels = box_with_knob
    episode, sampler = short_draw_episode(box_with_knob)
    config = sampler.config
    surface = episode.footprint.on(mesh)
    first = sampler.generate(mesh, seed=0, table_plane=np.array([0.0, 0.0, 1.0, 0.0]), on_faces=labels == 1)
    sampler.calls["on a part"] = 0
    assert surface.holds(first, labels == 1).sum() < 10  # 20 samples on and around the knob: too few of its holds
    drawn = episode.part_grasps(labels == 1)
    rounds = sampler.calls["on a part"]
    assert 1 < rounds <= config.part_draw_rounds
    assert np.array_equal(drawn.poses[: len(first)], first.poses)  # the first draw is the episode's seed's
    holding = int(surface.holds(drawn, labels == 1).sum())
    assert holding >= 10 or rounds == config.part_draw_rounds
    assert len(np.unique(np.round(drawn.contacts.reshape(len(drawn), -1), 6), axis=0)) > len(first)  # new draws
    episode.part_grasps(labels == 1)
    assert sampler.calls["on a part"] == rounds  # drawn once per part
    assert np.array_equal(episode.part_grasps(labels == 1, fill=False).poses, first.poses)


def test_the_feasibility_judgement_reads_a_parts_first_draw_only(box_with_knob) -> None:
    episode, sampler = short_draw_episode(box_with_knob)
    oracle = episode.plan("oracle")
    episode.feasibility(oracle, [0, 1])
    assert sampler.calls["on a part"] <= 2  # at most one draw on each part the first candidates miss
    judged = sampler.calls["on a part"]
    episode.slots(oracle)
    assert sampler.calls["on a part"] > judged  # the plan draws on until its slots can be filled


class KnobFirstPolicy:
    """A part policy that ranks, for every prompt, the candidates whose contacts lie on the knob first."""

    def __init__(self, labels: np.ndarray) -> None:
        self.labels = labels

    def select(self, grasps: GraspSet, mesh, face_probs: np.ndarray, top_k: int) -> list[np.ndarray]:
        _, _, faces = trimesh.proximity.closest_point(mesh, grasps.contacts[:, 0])
        order = np.argsort(self.labels[faces] != 1, kind="stable")[:top_k]
        return [order for _ in range(face_probs.shape[1])]


def test_the_top_up_follows_the_plans_own_ranking(box_with_knob) -> None:
    mesh, labels = box_with_knob
    context = EpisodeContext("box_with_knob", "box", ["body", "knob"], scene_seed=0)
    sampler = CountingSampler(AntipodalConfig(n_surface_samples=300, envelope_centres=0))
    episode = Episode(OutOfReachCell(mesh, np.inf), context, None, GroundTruth(mesh, labels), generator=sampler)
    everywhere = episode.grasps()
    # enough candidates hold the body, but the policy ranks the knob's first: the body's part is sampled too
    policy_plan = PartPlan("seggrasp", "test", labels, face_probabilities=np.eye(2)[labels],
                           policy=KnobFirstPolicy(labels))
    assert len(episode.planning_grasps(policy_plan, [0])) > len(everywhere)
    assert sampler.calls == {"everywhere": 1, "on a part": 1}


def test_segmenter_reuses_given_coarse_scores(cylinder) -> None:
    fake_votes = np.zeros((len(cylinder.mesh.faces), 3))
    fake_votes[:, 1] = 1.0
    segmenter = ObjectSegmenter(cylinder.mesh, ["top", "side", "bottom"], None, "votes", coarse_scores=fake_votes)
    plan = segmenter.plan("coarse", np.eye(4))
    assert np.all(plan.labels == 1)
    with pytest.raises(ValueError, match="planned from ground truth"):
        segmenter.plan("oracle", np.eye(4))  # the method never sees ground truth


@pytest.mark.slow
def test_perceived_episode_plans_on_the_camera_mesh(cell, cylinder) -> None:
    records = run_episode(cell, cylinder, "oracle", targets=["side"], top_k=2, perceive=True,
                          workspace=cell.workspace)
    assert all(r.executed for r in records)
    assert any(r.success for r in records)  # labels transferred from the twin to the fused mesh select the side


def test_every_failed_trial_is_named() -> None:
    lifted = GraspOutcome(reachable=True, lifted=True, lift_height=0.2)
    assert failure_of(None, None, None) == "no_grasp"
    assert failure_of(lifted, False, False) == "wrong_part"  # held, but by another part
    assert failure_of(lifted, True, True) == ""
    assert failure_of(GraspOutcome(True, False, 0.01, failure="slipped"), False, True) == "slipped"


def test_one_prompt_rule_everywhere() -> None:
    """Prompts match part names case-insensitively and stripped, in lookups and in remapping alike."""
    labels = PartLabels(["Handle", "body"], np.array([0, 1, -1, 0]))
    assert find_prompt(labels.parts, "  handle ") == 0 and find_prompt(labels.parts, "lid") is None
    assert labels.part_index(" BODY") == 1
    np.testing.assert_array_equal(labels.remap_to([" body ", "HANDLE"]), [1, 0, -1, 1])
    with pytest.raises(ValueError, match="not among"):
        prompt_index(["handle"], "lid")
