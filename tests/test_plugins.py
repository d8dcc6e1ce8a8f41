"""Extensions as a third party ships them: a package on sys.path with a ``*.dist-info/entry_points.txt``
adds a frame source and a command with zero edits to xcalib; a broken plugin is reported by name
(issue 28)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from xcalib.plugins import GROUPS, entries

SOURCE = textwrap.dedent('''
    """A frame source for folders holding a ``dets.csv`` (one synthetic frame per row)."""
    from pathlib import Path

    from xcalib.io.sources import register_source


    def _detect(path: Path) -> bool:
        return path.is_dir() and (path / "dets.csv").is_file()


    def _open(path: Path, *, camera=None, **options):
        from xcalib.data.synth import generate_frames, sample_site

        rows = (path / "dets.csv").read_text().split()
        return generate_frames(sample_site(0, "roadside"), len(rows), seed=1, render_images=False)


    register_source("csvdets", _detect, _open, description="CSV detections (plugin)", priority=10)
''')

COMMAND = textwrap.dedent('''
    import typer


    def register(app: typer.Typer) -> None:
        @app.command("hello", help="Say hello.\\n\\nExample: xcalib hello --name site")
        def hello(name: str = typer.Option("world", "--name")) -> None:
            typer.echo(f"hello {name}")
''')


def _package(root: Path, name: str, modules: dict[str, str], entry_points: str) -> Path:
    """A distribution as pip installs one: modules + ``<name>-0.1.dist-info`` with its entry points."""
    root.mkdir(parents=True, exist_ok=True)
    for mod, text in modules.items():
        (root / f"{mod}.py").write_text(text)
    info = root / f"{name}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))
    return root


def _run(root: Path, code: str) -> subprocess.CompletedProcess:
    import os

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), *sys.path]))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                          timeout=300)


def test_xcalib_declares_its_own_extensions():
    names = {e.name for e in entries("xcalib.commands")}
    assert {"calibrate", "bag", "version"} <= names
    assert {e.name for e in entries("xcalib.sources")} >= {"frames", "bags", "formats"}
    with pytest.raises(ValueError, match="xcalib.sources"):
        entries("xcalib.nope")
    assert "xcalib.cost_terms" in GROUPS


def test_the_built_in_fallback_declares_what_pyproject_declares():
    """``plugins.BUILTIN`` (used when xcalib's package metadata is not installed, e.g. a source tree on
    sys.path) and the ``[project.entry-points]`` of pyproject.toml name the same built-ins."""
    import tomllib

    from xcalib.plugins import BUILTIN

    declared = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    declared = declared["entry-points"]
    assert {"xcalib.formats", "xcalib.models"} <= set(BUILTIN) & set(declared)
    for group, table in BUILTIN.items():
        assert declared.get(group) == table, group


def test_built_in_formats_and_models_are_discovered_like_plugins(monkeypatch):
    """With no package metadata at all (as in a checkout whose install predates the declarations),
    the built-in formats and models still come through the entry-point registry, from the fallback."""
    from importlib import metadata

    from xcalib.formats import export
    from xcalib.plugins import load

    monkeypatch.setattr(metadata, "entry_points", lambda **kw: [])
    found = {e.name: e for e in entries("xcalib.formats")}
    assert list(found)[:len(export.FORMATS)] == list(export.FORMATS)
    assert all(found[n].dist == "xcalib" and load(found[n]) is f for n, f in export.FORMATS.items())
    assert export.calib_formats() == export.FORMATS and export.format_names(writable=True)[0] == "kitti"
    pytest.importorskip("torch")
    from xcalib.models import list_models
    from xcalib.models.registry import model_class

    models = {e.name: e for e in entries("xcalib.models")}
    assert {"fastmatch", "crlite", "crlite_2dpe", "calibrefine", "crlite_vit_exp1", "crlite_vit_exp3",
            "crlite_vit_exp4"} == set(models) and set(models) <= set(list_models())
    assert all(load(e) is model_class(n) for n, e in models.items())


def test_a_third_party_source_and_command_need_no_edit_to_xcalib(tmp_path):
    root = _package(tmp_path / "site", "xcalib_demo_plugin", {"csvdets_src": SOURCE, "hello_cmd": COMMAND}, """
        [xcalib.sources]
        csvdets = csvdets_src

        [xcalib.commands]
        hello = hello_cmd
    """)
    data = tmp_path / "recording"
    data.mkdir()
    (data / "dets.csv").write_text("a\nb\nc\n")
    run = _run(root, f"""
        from xcalib.io.sources import find_source, open_source
        from xcalib.cli import main
        print("source", find_source({str(data)!r}).name, len(open_source({str(data)!r})))
        raise SystemExit(main(["hello", "--name", "plugin"]))
    """)
    assert run.returncode == 0, run.stderr
    assert "source csvdets 3" in run.stdout and "hello plugin" in run.stdout
    helptext = _run(root, "from xcalib.cli import main; raise SystemExit(main(['--help']))")
    assert "hello" in helptext.stdout and "calibrate" in helptext.stdout


def test_a_broken_plugin_is_reported_by_name_and_the_rest_still_loads(tmp_path):
    root = _package(tmp_path / "site", "broken_plugin", {"nohook_cmd": "X = 1\n"}, """
        [xcalib.commands]
        ghost = no_such_module_anywhere
        nohook = nohook_cmd

        [xcalib.sources]
        ghostsrc = no_such_source_module

        [xcalib.cost_terms]
        ghostterm = no_such_term_module:factory

        [xcalib.formats]
        ghostfmt = nohook_cmd:X
    """)
    run = _run(root, """
        import warnings
        warnings.simplefilter("always")
        from xcalib.cli import COMMANDS
        from xcalib.io.sources import frame_sources
        from xcalib.calib.terms import cost_terms
        from xcalib.formats.export import calib_formats
        from xcalib.plugins import plugin_errors
        print("commands", sorted(COMMANDS))
        print("sources", sorted(s.name for s in frame_sources()))
        print("terms", sorted(cost_terms()), "formats", sorted(calib_formats()))
        print("errors", sorted(plugin_errors()))
    """)
    assert run.returncode == 0, run.stderr
    assert "'ghost'" in run.stderr and "no_such_module_anywhere" in run.stderr and "broken_plugin" in run.stderr
    assert "'nohook'" in run.stderr and "register(app)" in run.stderr
    assert "'ghostsrc'" in run.stderr
    assert "'calibrate'" in run.stdout and "'bag'" in run.stdout  # the built-ins still load
    assert "xcalib.commands:ghost" in run.stdout and "xcalib.sources:ghostsrc" in run.stdout
    assert "xcalib.cost_terms:ghostterm" in run.stdout and "'pose_prior'" in run.stdout  # reported; built-ins kept
    assert "'ghostfmt'" in run.stderr and "not a xcalib.formats.export.CalibFormat" in run.stderr
    assert "'kitti'" in run.stdout and "'ghostfmt'" not in run.stdout


COST_TERM = textwrap.dedent('''
    """A camera-height prior: the camera centre's height in the LiDAR frame (m) near a known value."""
    import inspect

    import numpy as np

    from xcalib.calib.cost import CostTerm


    class CameraHeightTerm(CostTerm):
        name = "camera_height"

        def __init__(self, height_m, sigma_m):
            self.height_m, self.sigma_m = float(height_m), float(sigma_m)

        def residuals(self, state):
            centre = -state.pose.R.T @ state.pose.t  # camera centre, LiDAR frame
            return np.array([(centre[2] - self.height_m) / self.sigma_m])


    def camera_height(ctx, *, height_m, sigma_m=0.05, log=""):
        if log:  # which stage of the calibration built the term (the test reads it)
            with open(log, "a") as f:
                f.write(" ".join(fr.function for fr in inspect.stack()[1:6]) + "\\n")
        return CameraHeightTerm(height_m, sigma_m)
''')


def test_a_third_party_cost_term_is_named_in_the_config_and_every_stage_uses_it(tmp_path):
    root = _package(tmp_path / "site", "xcalib_height_prior", {"height_term": COST_TERM}, """
        [xcalib.cost_terms]
        camera_height = height_term:camera_height
    """)
    log = tmp_path / "stages.txt"
    run = _run(root, f"""
        import json
        import numpy as np
        from xcalib.calib.api import calibrate
        from xcalib.calib.config import CalibConfig
        from xcalib.calib.cost import Occlusion
        from xcalib.calib.inputs import prepare_frames
        from xcalib.calib.pose import Pose
        from xcalib.calib.refine import FitContext, lsq, match_all
        from xcalib.calib.terms import CostSpec
        from xcalib.data.synth import generate_frames, sample_site

        site = sample_site(0, "roadside")
        frames = generate_frames(site, 8, seed=5, render_images=False)
        T = np.asarray(site.T_cam_lidar)
        height = lambda R, t: float((-np.asarray(R).T @ np.asarray(t))[2])
        h0 = height(T[:3, :3], T[:3, 3])
        cfg = CalibConfig(workers=1, cost_terms=(f"camera_height:height_m={{h0}},sigma_m=0.02,log={str(log)}",))
        assert CalibConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
        res = calibrate(frames, config=cfg, prior=T)
        print("calibrated", res.success, res.config.cost_terms[0].name)

        # the term moves the fit: a prior 0.3 m below the truth with 1 mm pulls the camera down to it
        cframes = prepare_frames(frames, site.intrinsics)[0]
        pairs = match_all(cframes, site.intrinsics, T[:3, :3], T[:3, 3])
        spec = CostSpec(Occlusion(), CalibConfig(cost_terms=(f"camera_height:height_m={{h0 - 0.3}},sigma_m=0.001",)).cost_terms)
        R0, t0, *_ = lsq(FitContext(cframes, pairs, site.intrinsics, Pose(T[:3, :3], T[:3, 3]), None, 2.0), 60)
        R1, t1, *_ = lsq(FitContext(cframes, pairs, site.intrinsics, Pose(T[:3, :3], T[:3, 3]), None, 2.0, spec), 60)
        print("pulled", round(h0 - height(R1, t1), 3), abs(height(R0, t0) - h0 + 0.3) > 0.2)
        try:
            CalibConfig(cost_terms=("camera_heigth",))
        except ValueError as exc:
            print("typo", exc)
        from xcalib.cli import main
        print("cli rc", main(["calibrate", ".", "--cost-term", "camera_height:height_mm=1"]))
    """)
    assert run.returncode == 0, run.stderr
    assert "calibrated True camera_height" in run.stdout
    pulled = run.stdout.split("pulled ")[1].split()
    assert abs(float(pulled[0]) - 0.3) < 0.02 and pulled[1] == "True"
    assert "no cost term named 'camera_heigth'" in run.stdout and "camera_height" in run.stdout.split("typo")[1]
    assert "cli rc 2" in run.stdout and "height_mm" in run.stderr  # the command line names the bad option
    stages = log.read_text()
    # (the outline refit is made once, in the uncertainty's ``_outline_fit``; ``fit_outline`` reads it)
    for stage in ("refine_step", "_focal_agrees", "_refit", "_scores", "_outline_fit", "_time_fit", "_pp_fit"):
        assert stage in stages, stage  # refinement, self-calibration, uncertainty, misfit refits


def test_cost_terms_are_registered_and_checked_by_name():
    from xcalib.calib.config import CalibConfig, TermSpec
    from xcalib.calib.terms import cost_terms

    assert {"box_edges", "pose_prior", "focal_scale", "principal_point", "time_offset"} <= set(cost_terms())
    cfg = CalibConfig(cost_terms=("pose_prior:sigma_deg=2,t_m=[0,0,1]",))
    assert cfg.cost_terms == (TermSpec("pose_prior", (("sigma_deg", 2), ("t_m", (0, 0, 1)))),)
    assert CalibConfig.from_dict(cfg.to_dict()) == cfg and CalibConfig().cost_terms == ()
    with pytest.raises(ValueError, match="refine_intrinsics"):
        CalibConfig(cost_terms=("focal_scale",))
    with pytest.raises(ValueError, match="sigmaa"):
        CalibConfig(cost_terms=("pose_prior:sigmaa=1",))
    with pytest.raises(ValueError, match="named twice"):
        CalibConfig(cost_terms=("pose_prior", "pose_prior"))


FORMAT = textwrap.dedent('''
    """A rig-pose YAML (``rigpose: 1`` then ``T_cam_lidar``: 16 numbers, row major)."""
    from pathlib import Path

    import numpy as np

    from xcalib.calib.result import CalibrationResult
    from xcalib.formats.export import CalibFormat


    def write(result, path):
        path = Path(path)
        path.write_text("rigpose: 1\\nT_cam_lidar: [" + ", ".join(repr(float(v)) for v in result.extrinsics.ravel()) + "]\\n")
        return [path]


    def read(path, repair=False):
        line = [l for l in Path(path).read_text().splitlines() if l.startswith("T_cam_lidar:")][0]
        T = np.array([float(v) for v in line.split("[", 1)[1].rstrip("]").split(",")]).reshape(4, 4)
        return CalibrationResult(success=True, rotation=T[:3, :3], translation=T[:3, 3], message="rigpose")


    def sniff(path):
        return path.suffix in (".yaml", ".yml") and path.read_text().startswith("rigpose:")


    FORMAT = CalibFormat("rigpose", "rig pose YAML (plugin)", "rig.yaml", write, read, sniff)
''')


def test_a_third_party_calibration_format_converts_and_is_detected_on_read(tmp_path):
    root = _package(tmp_path / "site", "xcalib_rigpose", {"rigpose_fmt": FORMAT}, """
        [xcalib.formats]
        rigpose = rigpose_fmt:FORMAT
    """)
    src = tmp_path / "calib.txt"
    src.write_text("P2: 700.0 0 600.0 0 0 700.0 180.0 0 0 0 1 0\nR0_rect: 1 0 0 0 1 0 0 0 1\n"
                   "Tr_velo_to_cam: 0 -1 0 0.1 0 0 -1 -0.2 1 0 0 -0.3\n")
    run = _run(root, f"""
        import json
        from xcalib.cli import main
        from xcalib.formats.export import detect_format, read_calibration
        assert main(["convert", {str(src)!r}, "--to", "rigpose", "--out", {str(tmp_path / "rig.yaml")!r}]) == 0
        print("detected", detect_format({str(tmp_path / "rig.yaml")!r}))
        assert main(["convert", {str(tmp_path / "rig.yaml")!r}, "--to", "json", "--out", {str(tmp_path / "back.json")!r},
                     "--json"]) == 0
        a, b = read_calibration({str(src)!r}), read_calibration({str(tmp_path / "back.json")!r})
        print("same", abs(a.extrinsics - b.extrinsics).max() < 1e-12)
        raise SystemExit(main(["convert", {str(src)!r}, "--to", "rigpos"]))
    """)
    assert "detected rigpose" in run.stdout and '"from": "rigpose"' in run.stdout and "same True" in run.stdout
    assert run.returncode != 0 and "rigpose" in run.stderr  # a typo lists the plugin among the writable formats


MODEL = textwrap.dedent('''
    """A tiny matching model: mean colour of each crop and mean point of each 3D crop, one linear layer each."""
    from dataclasses import dataclass

    from torch import nn

    from xcalib.models.base import Embeddings, MatchingModel
    from xcalib.models.registry import ModelConfig


    @dataclass(frozen=True)
    class MeanMatchConfig(ModelConfig):
        point_cloud_size: int = 16
        embed_dim: int = 8


    class MeanMatch(MatchingModel):
        config_class = MeanMatchConfig

        def __init__(self, config):
            super().__init__(config)
            e = int(self.config["embed_dim"])
            self.img, self.lid = nn.Linear(3, e), nn.Linear(3, e)

        def embed(self, batch):
            return Embeddings(self.img(batch.crops_2d.mean((2, 3))), self.lid(batch.crops_3d.mean(1)))
''')


def test_a_third_party_model_is_created_by_name_with_a_typed_config_and_trains_one_step(tmp_path):
    root = _package(tmp_path / "site", "xcalib_meanmatch", {"meanmatch": MODEL}, """
        [xcalib.models]
        meanmatch = meanmatch:MeanMatch
    """)
    tests = Path(__file__).resolve().parent
    run = _run(root, f"""
        import json, sys
        sys.path.insert(0, {str(tests)!r})
        import torch
        from _matching_frames import make_frames
        from xcalib.engine.trainer import XCALIB_RECIPE, train
        from xcalib.models import create_model, default_config, list_models

        m = create_model("meanmatch", embed_dim=4)
        print("created", type(m).__name__, m.typed_config.embed_dim, "meanmatch" in list_models(),
              default_config("meanmatch")["point_cloud_size"])
        for bad in ({{"embed_dimm": 4}}, {{"embed_dim": "4"}}):
            try:
                create_model("meanmatch", **bad)
            except ValueError as exc:
                print("refused", exc)
        try:
            create_model("fastmatch", embed_dimm=32)  # xcalib's own models: the same check
        except ValueError as exc:
            print("refused", exc)
        torch.manual_seed(0)
        tr = make_frames(2, 1)
        best = train("meanmatch", tr, tr, **XCALIB_RECIPE.kwargs(epochs=1, warmup_epochs=0, lr=1e-2),
                     output_dir={str(tmp_path / "run")!r}, progress=False, seed=0, frames_per_batch=2)
        hist = json.loads(open({str(tmp_path / "run" / "history.json")!r}).read())
        from xcalib.engine.matcher import Matcher
        back = Matcher.from_pretrained("meanmatch", weights=best, device="cpu")  # the typed config travelled with it
        print("trained", best.name, len(hist), hist[0]["train_loss_mean"] > 0, back.model.typed_config.embed_dim)
    """)
    assert run.returncode == 0, run.stderr
    assert "created MeanMatch 4 True 16" in run.stdout
    assert "unknown config key(s) 'embed_dimm' (did you mean 'embed_dim'?)" in run.stdout
    assert "'embed_dim' expects a int" in run.stdout
    assert run.stdout.count("did you mean 'embed_dim'") == 2  # fastmatch refuses the typo too
    assert "trained best.pth 1 True 8" in run.stdout
