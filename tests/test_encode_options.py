"""The encode option rules (encoder.presets.check_options): one function judges which options go
together, for the command line and for library callers alike, with the same one-line messages."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spcodec.cli import build_parser
from spcodec.cli.encode import encode_config
from spcodec.encoder.presets import (
    ENCODE_OPTIONS,
    PRESETS,
    RETRAINING_OPTIONS,
    SURVIVOR_OPTIONS,
    check_options,
    retrains,
)
from spcodec.errors import UsageError

ARGUMENTS = {"dataset": ["--dataset", "scenes/x"], "iterations": ["--iterations", "5"],
             "finish_iterations": ["--finish-iterations", "0"], "views": ["--views", "4"],
             "close_views": ["--close-views", "0"], "resolution": ["--resolution", "64"],
             "resume": ["--resume"], "checkpoint_every": ["--checkpoint-every", "0"],
             "downscale": ["--downscale", "2"], "nested": ["--nested"],
             "nested_full_share": ["--nested-full-share", "0.5"],
             "target_size": ["--target-size", "150k"], "target_psnr": ["--target-psnr", "30"],
             "patch_downsample": ["--patch-downsample", "2"], "prune": ["--prune", "uniform"],
             "no_retrain": ["--no-retrain"]}
"""Each judged option as a command line gives it (zeros included: given is given)."""


def _parsed(preset: str, names: set[str]):
    argv = ["encode", "in.ply", "-o", "out.spc", "--preset", preset]
    for name in sorted(names):
        argv += ARGUMENTS[name]
    return build_parser().parse_args(argv)


def _expected_problems(preset: str, names: set[str]) -> list[str]:
    """Every rule the options break, as the flags each rule's message must name."""
    retrain = "no_retrain" not in names and retrains(preset)
    problems = []
    if not retrain and names & set(RETRAINING_OPTIONS):
        problems.append("retraining")
    if len(names & set(SURVIVOR_OPTIONS)) > 1:
        problems.append("survivors")
    if "nested_full_share" in names and "nested" not in names:
        problems.append("nested")
    if not retrain and names & {"patch_downsample", "prune"}:
        problems.append("pruning")
    return problems


def test_every_judged_option_has_a_command_line_form():
    assert set(ARGUMENTS) == set(ENCODE_OPTIONS)
    args = _parsed("balanced", set(ENCODE_OPTIONS))
    assert all(getattr(args, name) is not None and getattr(args, name) is not False
               for name in ENCODE_OPTIONS)


@settings(max_examples=150, deadline=None)
@given(preset=st.sampled_from(sorted(PRESETS)),
       names=st.sets(st.sampled_from(sorted(ENCODE_OPTIONS)), max_size=5))
def test_the_command_line_and_the_library_agree(preset, names):
    """The command line refuses exactly what check_options refuses, with its message; what it
    accepts retrains exactly when check_options says so."""
    args = _parsed(preset, names)
    problems = _expected_problems(preset, names)
    options = {name: getattr(args, name) for name in ENCODE_OPTIONS}
    if problems:
        with pytest.raises(ValueError) as library:
            check_options(preset, **options)
        with pytest.raises(UsageError) as command:
            encode_config(args)
        message = str(library.value)
        assert str(command.value) == message and "\n" not in message
        first = problems[0]  # the rules are judged in order: the first broken one speaks
        named = {"retraining": RETRAINING_OPTIONS, "survivors": SURVIVOR_OPTIONS,
                 "nested": ("nested_full_share",), "pruning": ()}[first]
        for name in names & set(named):
            assert f"--{name.replace('_', '-')}" in message, (message, name)
    else:
        retrain = check_options(preset, **options)
        assert retrain == ("no_retrain" not in names and retrains(preset))
        assert (encode_config(args).retrain is not None) == retrain


@pytest.mark.parametrize("preset, options, message", [
    ("balanced", {"no_retrain": True, "iterations": 5, "resume": True},
     "--iterations, --resume only apply to retraining: drop --no-retrain or them"),
    ("transparent", {"views": 4},
     "--views only apply to retraining: drop --preset transparent (it never retrains) or them"),
    ("balanced", {"target_size": "150k", "target_psnr": 30.0},
     "--target-size and --target-psnr each choose how many patch Gaussians survive: give one of "
     "them"),
    ("lowrate", {"nested_full_share": 0.5},
     "--nested-full-share sets how --nested trains: give --nested too, or drop it"),
    ("transparent", {"prune": "uniform"},
     "--patch-downsample and --prune need retraining, which --preset transparent (it never "
     "retrains) leaves out (give --target-size to prune by importance without it)"),
    ("balanced", {"no_retrain": True, "iterations": 0},
     "--iterations only apply to retraining: drop --no-retrain or them"),
])
def test_a_library_caller_gets_the_command_lines_message(preset, options, message):
    with pytest.raises(ValueError) as caught:
        check_options(preset, **options)
    assert str(caught.value) == message


def test_unknown_presets_and_options_are_named():
    with pytest.raises(ValueError, match="unknown preset 'fast'"):
        check_options("fast")
    with pytest.raises(ValueError, match="unknown encode options iteration"):
        check_options("balanced", iteration=5)
    assert check_options("balanced") is True and check_options("transparent") is False
    assert check_options("highrate", no_retrain=False, nested=None) is True


@pytest.mark.parametrize("extra", [[], ["--target-size", "150k"], ["--target-psnr", "30"]])
def test_position_bits_given_are_kept_by_the_precision_search(extra):
    """Without retraining a preset's point and the targets choose the positions' grid by rate
    and distortion; a grid given with --position-bits is kept instead."""
    argv = ["encode", "in.ply", "-o", "out.spc", "--no-retrain", *extra]
    chosen = encode_config(build_parser().parse_args(argv))
    assert chosen.allocation is not None and chosen.allocation.position_bits
    given_ = encode_config(build_parser().parse_args(argv + ["--position-bits", "13"]))
    assert given_.allocation.position_bits == () and given_.patch.position_bits == 13


@pytest.mark.parametrize("extra, refused", [
    (["--no-retrain"], True), (["--no-sketch"], True), (["--no-retrain", "--preset", "transparent"], True),
    ([], False), (["--no-retrain", "--target-psnr", "30"], False)])
def test_tau_max_is_refused_where_no_sketch_is_built(extra, refused):
    """--tau-max tunes the sketch; an encode that builds none (a no-retrain preset's point,
    --no-sketch, transparent) says so in one line instead of ignoring it."""
    args = build_parser().parse_args(["encode", "in.ply", "-o", "out.spc", *extra,
                                      "--tau-max", "0.2"])
    if refused:
        with pytest.raises(UsageError, match="--tau-max sets the sketch's clusters"):
            encode_config(args)
    else:
        assert encode_config(args).refine.tau_max == 0.2
