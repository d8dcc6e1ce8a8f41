"""Option records of the wide public functions (issue 28: <= 8 parameters): the reference's keyword
arguments still work with the same defaults, a record can be passed whole, an unknown keyword is a
TypeError naming it and the accepted names, a value of the wrong type a clear error. Nothing heavy
runs: every refusal happens before any work."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path

import numpy as np
import pytest

import xcalib
from xcalib.options import Options, bind_positional, document, resolve, split_overrides


@dataclasses.dataclass(frozen=True)
class _Opts(Options):
    n: int = 3
    rate: float = 0.5
    name: str | None = None
    mode: "str" = "a"
    path: str | Path = "x"


def test_resolve_folds_overrides_and_keeps_defaults_in_the_record():
    assert resolve(_Opts, None, {}) == _Opts()
    base = _Opts(n=5)
    assert resolve(_Opts, base, {}) is base
    got = resolve(_Opts, base, {"rate": 1, "path": Path("y")})  # int for float, Path for str | Path
    assert got == _Opts(n=5, rate=1, path=Path("y")) and base.n == 5
    assert _Opts().replace(n=7).n == 7 and _Opts.field_names() == ("n", "rate", "name", "mode", "path")


def test_unknown_name_is_a_type_error_naming_it_and_the_accepted_ones():
    with pytest.raises(TypeError, match=r"f\(\) got an unexpected keyword argument 'rte' \(did you mean 'rate'\?\); "
                                        r"accepted: mode, n, name, path, rate"):
        resolve(_Opts, None, {"rte": 1}, where="f")
    with pytest.raises(TypeError, match="options must be a _Opts"):
        resolve(_Opts, {"n": 1}, {}, where="f")


def test_wrong_types_are_refused_naming_the_field():
    with pytest.raises(TypeError, match="_Opts: n must be int, got str '3'"):
        _Opts(n="3")
    with pytest.raises(TypeError, match="n must be int, got bool"):
        _Opts(n=True)
    with pytest.raises(TypeError, match="name must be str | None"):
        resolve(_Opts, None, {"name": 3})
    assert _Opts(n=np.int64(2), rate=np.float32(0.1)).n == 2  # numpy scalars are numbers


def test_literal_fields_refuse_other_values():
    from xcalib.batch import BatchOptions

    with pytest.raises(ValueError, match=r"executor must be one of \['process', 'ray', 'serial'\], got 'threads'"):
        BatchOptions(executor="threads")


def test_positional_and_split_helpers():
    assert bind_positional(("a", "b"), (1,), {"c": 2}, "f") == {"a": 1, "c": 2}
    with pytest.raises(TypeError, match="multiple values for argument 'a'"):
        bind_positional(("a",), (1,), {"a": 2}, "f")
    with pytest.raises(TypeError, match="at most 1 optional positional"):
        bind_positional(("a",), (1, 2), {}, "f")
    assert split_overrides({"n": 1, "z": 2}, [_Opts, ("z",)], "f") == [{"n": 1}, {"z": 2}]
    with pytest.raises(TypeError, match="unexpected keyword argument 'q'.*accepted: mode, n, name, path, rate, z"):
        split_overrides({"q": 1}, [_Opts, ("z",)], "f")


def test_document_lists_the_record_fields_with_their_defaults():
    @document(_Opts, positional=("n",))
    def f(a, *args, options=None, **overrides):
        return resolve(_Opts, options, bind_positional(("n",), args, overrides, "f"), where="f")

    p = inspect.signature(f).parameters
    assert list(p) == ["a", "n", "rate", "name", "mode", "path", "options"]
    assert p["n"].kind is inspect.Parameter.POSITIONAL_OR_KEYWORD and p["rate"].kind is inspect.Parameter.KEYWORD_ONLY
    assert p["rate"].default == 0.5 and f(0, 4, rate=1.0) == _Opts(n=4, rate=1.0)


# ------------------------------------------------------------------ the public functions
def _public():
    from xcalib.batch import calibrate_many
    from xcalib.data.synth.generate import write_site
    from xcalib.deploy.build import build
    from xcalib.deploy.ort_runtime import OnnxMatcher
    from xcalib.engine.matcher import Matcher
    from xcalib.io.bags import BagFrames, write_bag
    from xcalib.oneshot.adapt import adapt_model
    from xcalib.oneshot.bootstrap import bootstrap
    from xcalib.oneshot.session import OneShotSession
    from xcalib.viz.report import write_calibration_report

    img, pc, b2, b3 = np.zeros((8, 8, 3), np.uint8), np.zeros((1, 3)), np.zeros((0, 4)), np.zeros((0, 6))
    # (name, a call with one unknown keyword, an old keyword with its default)
    return [
        ("train", lambda **k: xcalib.train("fastmatch", [], None, **k), xcalib.train, ("epochs", 10)),
        ("match", lambda **k: Matcher.match(None, img, pc, b2, b3, **k), Matcher.match, ("top_k", 1)),
        ("match", lambda **k: OnnxMatcher.match(None, img, pc, b2, b3, **k), OnnxMatcher.match, ("geometry", "auto")),
        ("build", lambda **k: build(None, **k), build, ("precision", "fp16")),
        ("OneShotSession", lambda **k: OneShotSession(None, None, **k), OneShotSession, ("match_threshold", 0.7)),
        ("OneShotSession.adapt", lambda **k: OneShotSession.adapt(None, **k), OneShotSession.adapt, ("box_gain", "auto")),
        ("adapt_model", lambda **k: adapt_model(None, [], [], steps=1, n_points=8, device="cpu", **k), adapt_model,
         ("anchor", 1e-2)),
        ("bootstrap", lambda **k: bootstrap([], None, "s", **k), bootstrap, ("steps", 600)),
        ("BagFrames", lambda **k: BagFrames("missing.bag", **k), BagFrames, ("tolerance_s", 0.05)),
        ("write_bag", lambda **k: write_bag("x.mcap", [], **k), write_bag, ("start_s", 1_700_000_000.0)),
        ("write_site", lambda **k: write_site("nowhere", 0, 0, 0, **k), write_site, ("image_format", "jpeg")),
        ("calibrate_many", lambda **k: calibrate_many([], "nowhere", **k), calibrate_many, ("executor", "process")),
        ("draw_matching_overlay", lambda **k: xcalib.draw_matching_overlay(img, pc, b2, b3, **k),
         xcalib.draw_matching_overlay, ("output_height", 420)),
        ("draw_calibration_overlay", lambda **k: xcalib.draw_calibration_overlay(img, **k),
         xcalib.draw_calibration_overlay, ("max_points", 6000)),
        ("write_calibration_report", lambda **k: write_calibration_report("nowhere", None, [], **k),
         write_calibration_report, ("max_frames", 4)),
    ]


def test_every_wide_function_refuses_an_unknown_keyword_before_any_work():
    pytest.importorskip("torch")
    for name, call, _, _ in _public():
        with pytest.raises(TypeError, match=rf"^{name}\(\) got an unexpected keyword argument 'zzqq'; accepted: "):
            call(zzqq=1)


def test_every_wide_function_still_shows_its_keywords_and_defaults():
    pytest.importorskip("torch")
    for name, _, fn, (kw, default) in _public():
        p = inspect.signature(fn).parameters
        assert kw in p and p[kw].default == default, (name, kw)
        assert "options" in p, name


def test_match_keeps_the_reference_positional_order():
    pytest.importorskip("torch")
    from xcalib.engine.host import MatchOptions, match_request

    arrays = (1, 2, 3, 4)
    frame, o = match_request(arrays, (3, 0.5, True, "off"), None, {"assignment": "hungarian", "box7": 9})
    assert o == MatchOptions(top_k=3, match_threshold=0.5, return_latency=True, validate="off", assignment="hungarian")
    assert frame.box7 == 9 and frame.image == 1
    _, o2 = match_request(arrays, (), MatchOptions(top_k=2), {"validate": "strict"})
    assert (o2.top_k, o2.validate) == (2, "strict")
    with pytest.raises(TypeError, match="top_k must be int"):
        match_request(arrays, ("one",), None, {})


def test_train_options_from_recipe_and_back():
    from xcalib.engine.recipes import REFERENCE_RECIPE, XCALIB_RECIPE, TrainOptions

    assert TrainOptions().recipe == REFERENCE_RECIPE
    o = TrainOptions.from_recipe(XCALIB_RECIPE, seed=0)
    assert o.recipe == XCALIB_RECIPE and o.seed == 0 and o.output_dir == "runs/train"
    with pytest.raises(TypeError, match="epochs must be int"):
        TrainOptions(epochs="3")
    with pytest.raises(TypeError, match="did you mean 'epochs'"):
        TrainOptions.from_recipe(XCALIB_RECIPE, epoch=3)


def test_a_record_and_the_keywords_give_the_same_picture():
    from xcalib.viz.matching import MatchingOverlayOptions

    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    pc = rng.normal(0, 5, (200, 3))
    b2 = np.array([[10, 10, 40, 50]], np.float32)
    b3 = np.array([[4, 0, 0, 6, 2, 2]], np.float32)
    by_kw = xcalib.draw_matching_overlay(img, pc, b2, b3, [(0, 0, 0.9)], output_height=200, title="t")
    by_rec = xcalib.draw_matching_overlay(img, pc, b2, b3, [(0, 0, 0.9)],
                                          options=MatchingOverlayOptions(output_height=200, title="t"))
    mixed = xcalib.draw_matching_overlay(img, pc, b2, b3, [(0, 0, 0.9)], options=MatchingOverlayOptions(title="t"),
                                         output_height=200)
    assert by_kw.shape[0] >= 200 and np.array_equal(by_kw, by_rec) and np.array_equal(by_kw, mixed)
