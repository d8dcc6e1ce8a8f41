"""Export a matching model to ONNX graphs (torch; TorchScript-based ``torch.onnx.export``).

torch 2.13 has two exporters: the torch.export-based one (``dynamo=True``, the default) needs
the ``onnxscript`` package, which xcalib does not depend on; the TorchScript-based one
(``dynamo=False``) is deprecated but present and supports opsets up to 20, so xcalib uses it
with opset :data:`OPSET` = 20 and constant folding.

Graphs (every one has a single dynamic batch axis, see :mod:`xcalib.deploy.chunking`):

* ``image_embed.onnx``: image_crops [N,3,S,S], boxes_2d [N,4] px, image_wh [N,2] px ->
  img_embed [N,E] (+ model extras such as calibrefine's cls_img / pos_img).
* ``lidar_embed.onnx``: lidar_crops [M,P,3] box-frame m, boxes_3d [M,7] box7 m,
  point_counts [M] -> lid_embed [M,E] (+ extras).
* ``pair_score.onnx`` (families "hybrid" and "pairwise" only): the embedding outputs of both
  sides gathered per pair, [B,...] -> logit [B] (raw; the sigmoid is host-side).

Inputs a model does not use are pruned from its graphs by the exporter; the manifest lists the
inputs each graph really has. Family "cosine" (ViT models) scores on the host (cosine of the
L2-normalised embeddings); "hybrid" (crlite, crlite_2dpe) runs the pair graph on each row's
top-k cosine candidates; "pairwise" (calibrefine, fastmatch) on all N*M pairs.

The image and LiDAR graphs are traced from the model's own ``embed`` with the other modality
fixed to constants (folded away), so they compute exactly what the model computes per side.
"""

from __future__ import annotations

import contextlib
import copy
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch import nn

from ..data.crops import FrameInputs
from ..models.base import MatchingModel
from .errors import ExportError
from .manifest import GraphInfo, TensorInfo, sha256_file
from .onnx_feeds import IMAGE_INPUTS, LIDAR_INPUTS, frame_feeds, pair_feeds

__all__ = ["OPSET", "EXPORTER", "FAMILIES", "family_of", "ExportPlan", "make_plan", "export_plan",
           "run_torch", "export_mode", "cpu_copy"]

OPSET = 20
EXPORTER = f"torch.onnx.export (TorchScript-based, dynamo=False), torch {torch.__version__}"

# model name -> family; the pair graph is the model's own ``score_pairs``
FAMILIES = {
    "crlite": "hybrid", "crlite_2dpe": "hybrid",
    "crlite_vit_exp1": "cosine", "crlite_vit_exp3": "cosine", "crlite_vit_exp4": "cosine",
    "calibrefine": "pairwise", "fastmatch": "pairwise",
}
# families whose embeddings depend on the other detections of the frame (no N/M chunking)
JOINT_EMBEDDING = {"crlite_vit_exp4"}
# models that cannot be exported yet, with the reason
NOT_EXPORTABLE: dict[str, str] = {}



def family_of(model_name: str) -> str:
    if model_name in NOT_EXPORTABLE:
        raise ExportError(f"model {model_name!r} cannot be exported to ONNX: {NOT_EXPORTABLE[model_name]}")
    if model_name not in FAMILIES:
        raise ExportError(f"model {model_name!r} has no ONNX export plan; exportable: {sorted(FAMILIES)}")
    return FAMILIES[model_name]


# ---------------------------------------------------------------------------------- wrappers
def _dummy_side(inputs: FrameInputs, side: str) -> dict[str, torch.Tensor]:
    img, lid = frame_feeds(inputs)
    return {k: torch.from_numpy(v.copy()) for k, v in (img if side == "image" else lid).items()}


class _SideEmbed(nn.Module):
    """One modality's embedding outputs; the other modality is a constant (folded away)."""

    def __init__(self, model: nn.Module, side: str, other: dict[str, torch.Tensor], out_keys: Sequence[str]):
        super().__init__()
        self.model, self.side, self.other, self.out_keys = model, side, other, list(out_keys)

    def forward(self, crops: torch.Tensor, boxes: torch.Tensor, aux: torch.Tensor):
        from ..models.inputs import ModelBatch

        o = self.other
        seg = torch.zeros_like(boxes[:, 0], dtype=torch.long)
        if self.side == "image":
            b = ModelBatch(crops, o["lidar_crops"], boxes, aux, o["boxes_3d"], o["point_counts"], seg,
                           torch.zeros(len(o["boxes_3d"]), dtype=torch.long), 1)
        else:
            b = ModelBatch(o["image_crops"], crops, o["boxes_2d"], o["image_wh"], boxes, aux,
                           torch.zeros(len(o["boxes_2d"]), dtype=torch.long), seg, 1)
        emb = self.model.embed(b)
        main = emb.img if self.side == "image" else emb.lid
        return tuple([main] + [emb.extra[k] for k in self.out_keys[1:]])


class _PairScore(nn.Module):
    """Pair graph: the model's own ``score_pairs(*pair tensors) -> [B]`` logits."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, *x):
        return self.model.score_pairs(*x)


# ---------------------------------------------------------------------------------- plan
@dataclass
class GraphPlan:
    """One graph: the module exported, and ``reference`` (default: the same module), the torch
    computation the graph is checked against (exp4: the model's own sparse GNN code)."""

    name: str
    module: nn.Module
    input_names: list[str]
    output_names: list[str]
    axis: str
    role: str
    reference: nn.Module | None = None


@dataclass
class ExportPlan:
    """What to export for one model: graphs (torch modules) and the host-side settings."""

    model_name: str
    family: str
    graphs: list[GraphPlan]
    host: dict


@contextlib.contextmanager
def export_mode():
    """Disable the Transformer fast path while tracing and restore the previous setting."""
    prev = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        yield
    finally:
        torch.backends.mha.set_fastpath_enabled(prev)


def _side_keys(model: nn.Module, probe: FrameInputs) -> tuple[list[str], list[str]]:
    """Output names of the image / LiDAR graphs, from the model's embedding extras."""
    from ..models.inputs import ModelBatch

    with torch.inference_mode(), export_mode():
        emb = model.embed(ModelBatch.from_frames([probe], "cpu"))
    img, lid = ["img_embed"], ["lid_embed"]
    for k, v in emb.extra.items():
        is_img, is_lid = "img" in k, "lid" in k
        if is_img == is_lid or v.shape[0] != (probe.num_2d if is_img else probe.num_3d):
            raise ExportError(f"{model.model_name}: embedding extra {k!r} {tuple(v.shape)} cannot be assigned to "
                              "one modality (expected a name containing 'img' or 'lid' and one row per detection)")
        (img if is_img else lid).append(k)
    return img, lid


def make_plan(model: nn.Module, probe: FrameInputs) -> ExportPlan:
    """Export plan of ``model`` (a CPU, eval-mode copy); ``probe`` is a small frame used for the
    constant side and to discover the embedding outputs."""
    name = model.model_name
    family = family_of(name)
    img_keys, lid_keys = _side_keys(model, probe)
    graphs = [
        GraphPlan("image_embed", _SideEmbed(model, "image", _dummy_side(probe, "lidar"), img_keys),
                  list(IMAGE_INPUTS), img_keys, "N", "image"),
        GraphPlan("lidar_embed", _SideEmbed(model, "lidar", _dummy_side(probe, "image"), lid_keys),
                  list(LIDAR_INPUTS), lid_keys, "M", "lidar"),
    ]
    if name == "crlite_vit_exp4":  # sparse per-frame kNN GNN -> dense export form, checked against the model
        from .exp4_dense import Exp4DenseSide

        for g, side in zip(graphs, ("image", "lidar")):
            g.reference, g.module = g.module, Exp4DenseSide(model, side)
    host = {"top_k": None, "fill_value": None, "pair_activation": None,
            "joint_embedding": name in JOINT_EMBEDDING}
    if family in ("hybrid", "pairwise"):
        if type(model).score_pairs is MatchingModel.score_pairs:
            raise ExportError(f"model {name!r}: no score_pairs (pair head) for family {family!r}")
        graphs.append(GraphPlan("pair_score", _PairScore(model), img_keys + lid_keys, ["logit"],
                                "B", "stage2" if family == "hybrid" else "pairwise"))
        host["pair_activation"] = "sigmoid"
    if family == "hybrid":
        host["top_k"] = int(getattr(model, "top_k", 10))
        host["fill_value"] = float(model.fill_value)
    for g in graphs:  # wrappers start in training mode; the exporter restores that mode after tracing
        g.module.eval()
        if g.reference is not None:
            g.reference.eval()
    return ExportPlan(name, family, graphs, host)


def _torch_inputs(g: GraphPlan, feeds: dict[str, np.ndarray]) -> tuple[torch.Tensor, ...]:
    return tuple(torch.from_numpy(np.ascontiguousarray(feeds[n])) for n in g.input_names)


def run_torch(g: GraphPlan, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The torch reference of a graph on numpy feeds -> {output name: array}."""
    mod = g.reference if g.reference is not None else g.module
    mod.eval()
    with torch.inference_mode(), export_mode():
        out = mod(*_torch_inputs(g, feeds))
    out = out if isinstance(out, tuple) else (out,)
    return {n: o.float().numpy() for n, o in zip(g.output_names, out)}


def _tensor_info(vi, axis: str) -> TensorInfo:
    t = vi.type.tensor_type
    shape = [d.dim_param if d.dim_param else int(d.dim_value) for d in t.shape.dim]
    import onnx

    return TensorInfo(vi.name, shape, onnx.helper.tensor_dtype_to_np_dtype(t.elem_type).name)


def export_graph(g: GraphPlan, feeds: dict[str, np.ndarray], path: Path, opset: int = OPSET) -> GraphInfo:
    """Trace one graph with example ``feeds`` and write it to ``path``."""
    import onnx

    args = _torch_inputs(g, feeds)
    dyn = {n: {0: g.axis} for n in g.input_names + g.output_names}
    try:
        with torch.no_grad(), export_mode(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # deprecation of the TorchScript exporter, tracer warnings
            torch.onnx.export(g.module, args, str(path), dynamo=False, opset_version=opset,
                              input_names=g.input_names, output_names=g.output_names, dynamic_axes=dyn,
                              do_constant_folding=True, export_params=True)
    except Exception as exc:  # noqa: BLE001 - the exporter raises many types
        raise ExportError(f"export of graph {g.name!r} to {path} failed: {type(exc).__name__}: {exc}") from exc
    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    return GraphInfo(file=path.name, sha256=sha256_file(path),
                     inputs=[_tensor_info(v, g.axis) for v in proto.graph.input],
                     outputs=[_tensor_info(v, g.axis) for v in proto.graph.output], axis=g.axis, role=g.role)


def export_plan(plan: ExportPlan, example: FrameInputs, folder: Path, opset: int = OPSET) -> dict[str, GraphInfo]:
    """Export every graph of ``plan`` into ``folder`` traced on ``example`` (needs N, M >= 2)."""
    img, lid = frame_feeds(example)
    out: dict[str, GraphInfo] = {}
    side_out: dict[str, dict[str, np.ndarray]] = {}
    for g in plan.graphs:
        if g.role == "image":
            feeds = img
        elif g.role == "lidar":
            feeds = lid
        else:
            n, m = example.num_2d, example.num_3d
            rows, cols = np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
            feeds = pair_feeds(side_out["image"], side_out["lidar"], rows, cols)
        out[g.name] = export_graph(g, feeds, Path(folder) / f"{g.name}.onnx", opset)
        if g.role in ("image", "lidar"):
            side_out[g.role] = run_torch(g, feeds)
    return out


def cpu_copy(model: nn.Module) -> nn.Module:
    """An eval-mode CPU deep copy (the caller's model keeps its device and mode)."""
    m = copy.deepcopy(model).cpu().eval()
    return m
