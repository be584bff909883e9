"""--target-psnr: the smallest file whose close-up reaches the target, or a one-line refusal."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spcodec
from spcodec.cli import main
from spcodec.encoder.config import EncoderConfig, RetrainConfig
from spcodec.encoder.pipeline import encode
from spcodec.encoder.presets import aimed
from spcodec.encoder.qualitycontrol import (
    COUNT_TOLERANCE,
    CloseupJudge,
    check_reachable,
    fewest_reaching,
    smallest_reaching,
)
from spcodec.errors import UsageError
from spcodec.imaging.evaluate import EvalConfig, evaluate_against_reference
from spcodec.synthetic import make_scene

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def scene():
    return make_scene(5, curves=4, per_curve=150, blobs=900, sh_degree=1).cloud


@given(st.integers(10, 5000), st.floats(0.05, 0.95), st.floats(20, 50))
def test_fewest_reaching_finds_the_threshold_count(upper, share, slope):
    """A quality that rises with the count crosses the target at some count; the search returns
    a count that reaches it, within the tolerance of the crossing."""
    crossing = max(1, int(share * upper))

    def psnr_of(count: int) -> float:
        return 30.0 + slope * (count - crossing) / upper

    plan = fewest_reaching(30.0, upper, psnr_of)
    assert plan.reached and psnr_of(plan.count) >= 30.0 and plan.psnr == psnr_of(plan.count)
    assert plan.count - crossing <= max(1, COUNT_TOLERANCE * upper)
    # every Gaussian, one tolerance fewer (the top first), then bisection's
    assert len(plan.judged) <= 3 + int(np.ceil(np.log2(1 / COUNT_TOLERANCE)))


@given(st.integers(2, 5000), st.integers(1, 60), st.data())
def test_a_guided_search_finds_the_smallest_reaching_whatever_its_guide(width, slack, data):
    """smallest_reaching with any falling guide (a wrong one too) returns an x that reaches,
    with x - slack short (or at the bracket's low end), in at most thrice bisection's
    judgements plus one."""
    slack = min(slack, width)
    crossing = data.draw(st.integers(1, width), label="crossing")
    guide = data.draw(st.sampled_from(["exact", "reversed", "flat", "steps"]), label="guide")
    loss = {"exact": lambda x: 1.0 / (1 + x), "reversed": lambda x: float(width - x) ** 3,
            "flat": lambda x: 1.0, "steps": lambda x: float((width - x) // 7)}[guide]
    judged = {width: 40.0}
    calls = []

    def psnr_of(x: int) -> float:
        calls.append(x)
        return 30.0 + (x - crossing) * 0.01 + (0.0 if x >= crossing else -0.5)

    found = smallest_reaching(30.0, 0, width, psnr_of, judged, slack, loss)
    assert judged[found] >= 30.0 and found >= crossing
    assert found - slack < crossing
    assert len(calls) == len(set(calls))  # nothing judged twice
    assert len(calls) <= 3 * int(np.ceil(np.log2(max(width / slack, 1)))) + 1


@given(st.integers(8, 80), st.floats(0.05, 0.95), st.floats(1e-6, 1e-3), st.floats(0.5, 20.0),
       st.integers(0, 2**32 - 1))
def test_a_search_guided_by_the_predicted_distortion_takes_few_judgements(points, share, m0,
                                                                          gain, seed):
    """Along a precision curve whose rendered MSE is what the search predicted (the finest
    point's error plus a multiple of each point's predicted distortion), the smallest point
    that reaches is found in at most four judgements below the finest, where bisection takes
    log2 of the points."""
    distortion = np.sort(np.random.default_rng(seed).pareto(1.0, points))[::-1].copy()
    distortion[-1] = 0.0

    def psnr_of(i: int) -> float:
        return float(-10 * np.log10(m0 * (1 + gain * distortion[i] / distortion[0])))

    answer = max(1, int(share * (points - 1)))
    target = (psnr_of(answer - 1) + psnr_of(answer)) / 2  # between two points, clear of rounding
    guided = {points - 1: psnr_of(points - 1)}
    found = smallest_reaching(target, -1, points - 1, psnr_of, guided,
                              loss=lambda i: float(distortion[i]))
    bisected = {points - 1: psnr_of(points - 1)}
    assert found == smallest_reaching(target, -1, points - 1, psnr_of, bisected)
    assert psnr_of(found) >= target and (found == 0 or psnr_of(found - 1) < target)
    assert len(guided) - 1 <= 4


def test_when_one_tolerance_less_falls_short_every_gaussian_is_kept_after_one_judgement():
    calls = []

    def psnr_of(count: int) -> float:
        calls.append(count)
        return 40.0 if count == 1000 else 39.0

    plan = fewest_reaching(39.5, 1000, psnr_of, {1000: 40.0})
    assert plan.count == 1000 and plan.reached and calls == [1000 - COUNT_TOLERANCE * 1000]


def test_a_target_beyond_every_count_is_refused_with_the_best_reachable():
    plan = fewest_reaching(45.0, 100, lambda count: 30.0 + count / 10)
    assert not plan.reached and plan.count == 100 and plan.psnr == 40.0
    with pytest.raises(UsageError, match=r"out of reach.*reaches 40.00 dB") as err:
        check_reachable(45.0, plan, retraining=False)
    assert "\n" not in str(err.value)
    check_reachable(40.5, plan, retraining=True)  # retraining may still get there: try it
    with pytest.raises(UsageError, match="about 41.0 dB after"):
        check_reachable(42.0, plan, retraining=True)


def _closeup_psnr(data: bytes, scene) -> float:
    report = evaluate_against_reference(spcodec.decode(data), scene, EvalConfig(
        device="cpu", closeups=(0.5,)))
    return report.framing(0.5).psnr


@pytest.mark.slow
def test_without_retraining_the_file_is_the_smallest_that_reaches_the_target(scene):
    full = encode(scene, EncoderConfig(seed=3))
    target = _closeup_psnr(full.data, scene) - 4.0
    result = encode(scene, EncoderConfig(seed=3, target_psnr=target))
    reached = _closeup_psnr(result.data, scene)
    assert reached >= target and len(result.data) < len(full.data)
    aim = result.stats.quality_target
    assert aim["psnr_without_retraining"] == pytest.approx(reached, abs=0.01)
    assert result.stats.quality.closeups[0].psnr == pytest.approx(reached, abs=0.01)
    # what the search judged: every count below the one chosen fell short of the target
    assert CloseupJudge(scene, device="cpu")(spcodec.decode(result.data)) == pytest.approx(
        reached, abs=0.01)
    assert aim["largest_count_short"] >= aim["count_without_retraining"] - max(
        1, COUNT_TOLERANCE * aim["patch_gaussians"])


@pytest.mark.slow
def test_without_retraining_the_precision_is_the_smallest_point_of_the_curve_that_reaches(scene):
    """aimed() bisects the precision curve on real files: the chosen point reaches the target
    with every Gaussian kept, the next smaller one judged fell short, and the file written is
    the one judged (its close-up PSNR within 0.3 dB above the target once the count is fitted)."""
    full = encode(scene, EncoderConfig(seed=3))
    target = _closeup_psnr(full.data, scene) - 3.0
    result = encode(scene, aimed(EncoderConfig(seed=3), target))
    precision = result.stats.quality_target["precision"]
    judged = {int(i): v for i, v in precision["judged"].items()}
    verified = {int(i): v for i, v in precision["verified"].items()}
    chosen = precision["chosen_point"]
    assert verified[chosen] >= target and precision["curve_points"] > 1
    assert chosen == 0 or judged[chosen - 1] < target or verified[chosen - 1] < target
    assert max(judged) == precision["curve_points"] - 1  # the finest point is judged first
    reached = _closeup_psnr(result.data, scene)
    assert target <= reached == pytest.approx(
        result.stats.quality_target["psnr_without_retraining"], abs=0.01)
    assert len(result.data) < len(full.data)


def test_a_quality_target_beyond_the_finest_precision_names_what_it_reaches(scene):
    with pytest.raises(UsageError, match=r"out of reach without retraining: the finest "
                       r"precision, every Gaussian kept, reaches \d+\.\d\d dB") as err:
        encode(scene, aimed(EncoderConfig(seed=3), 99.0))
    assert "\n" not in str(err.value)


@pytest.mark.training
def test_retrained_files_reach_the_target_with_fewer_gaussians(scene):
    quick = RetrainConfig(iterations=60, finish_iterations=16, views=8, resolution=64,
                          importance_views=8, close_views=4, close_resolution=128, close_crop=48)
    full = encode(scene, EncoderConfig(seed=3))
    target = _closeup_psnr(full.data, scene) - 4.0
    result = encode(scene, EncoderConfig(seed=3, target_psnr=target, retrain=quick,
                                         max_sketch_share=None))
    aim = result.stats.quality_target
    assert aim["reached"] and aim["count_retrained"] <= aim["count_without_retraining"]
    assert _closeup_psnr(result.data, scene) >= target - 0.1  # the finish may move it a little


def test_target_psnr_errors_are_one_line_and_write_nothing(tmp_path, capsys, scene):
    ply, out = tmp_path / "s.ply", tmp_path / "s.spc"
    spcodec.write_ply(ply, scene)
    for argv, message in [
        (["--target-psnr", "5"], "--target-psnr: must be a number in 10..100"),
        (["--target-psnr", "40", "--target-size", "20k"], "give one of them"),
        (["--target-psnr", "99", "--no-retrain"], "out of reach"),
    ]:
        code = main(["encode", str(ply), "-o", str(out), "--quiet", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert code != 0 and len(err) == 1 and message in err[0], err
        assert not out.exists()


def test_a_config_with_both_targets_is_refused(scene):
    with pytest.raises(UsageError, match="one target"):
        encode(scene, dataclasses.replace(EncoderConfig(), target_size=10_000, target_psnr=30.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(20.0, 60.0), min_size=1, max_size=9, unique=True),
       st.lists(st.floats(0.0, 3.0), min_size=9, max_size=9), st.floats(20.0, 60.0))
def test_a_precision_short_at_the_evaluations_resolution_steps_up_the_curve(small, drops, target):
    """The curve is bisected on the judge's small views; its answer is judged again at the
    evaluation's resolution, and while it falls short there the next finer point is taken
    (never a pruned file: pruning comes after, from the verified point)."""
    import types

    from spcodec.encoder import sizing as sizing_module
    from spcodec.encoder.patch import PatchEncoder
    from spcodec.encoder.presets import preset_config

    small = sorted(small)  # the judged PSNR rises along the curve
    full = [s - d for s, d in zip(small, drops)]

    class Point:
        def __init__(self, i: int) -> None:
            self.i = i
            self.distortion = float(len(small) - i)  # the search's guide: it falls along the curve

        def patch_config(self, base):
            return dataclasses.replace(base, entry_counts={"point": self.i})

        def describe(self) -> dict:
            return {"point": self.i}

    judge = type("Judge", (), {"__call__": lambda self, point: small[point],
                               "verify": lambda self, point, predicted=None: full[point]})()
    config = aimed(preset_config("balanced", EncoderConfig(), point=False), target)
    sizing = sizing_module.QualityTarget.__new__(sizing_module.QualityTarget)
    sizing.config, sizing.target, sizing.judge, sizing.record = config, target, judge, {}
    sizing.precision_search = lambda *args: types.SimpleNamespace(
        curve=lambda: [Point(i) for i in range(len(small))])
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sizing_module, "pruned_file", lambda writer, encoder, cloud, weights, n:
                      types.SimpleNamespace(data=encoder.config.entry_counts["point"]))
        patch.setattr(sizing_module, "decode_layers", lambda point: types.SimpleNamespace(
            cloud=point))
        if small[-1] < target:
            with pytest.raises(UsageError, match="out of reach without retraining"):
                sizing.allocate([], None, None, PatchEncoder(config.patch), None)
            return
        sizing.allocate([], None, None, PatchEncoder(config.patch), None)
    first = min(i for i, s in enumerate(small) if s >= target)
    reaching = [i for i in range(first, len(small)) if full[i] >= target]
    chosen = reaching[0] if reaching else len(small) - 1
    precision = sizing.record["quality_target"]["precision"]
    assert precision["chosen_point"] == chosen
    assert sizing.allocated_psnr == full[chosen]
    assert sorted(int(i) for i in precision["verified"]) == list(range(first, chosen + 1))
