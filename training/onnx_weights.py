"""A shipped MigrationNet ONNX model back into PyTorch, so a fine-tune can start from exactly what ships.

The exporter folds each batch norm into the convolution before it, so the graph holds one weight and
one bias per convolution. They go back into the PyTorch net in execution order: the convolution
takes the folded weight, its batch norm becomes the identity plus the folded bias (mean 0, variance
1 − eps, scale 1). In eval mode that is the exported function exactly (`check_parity`); a fine-tune
from it keeps the batch norms in eval mode (`freeze_batch_norm`), since batch statistics of the
folded activations would not be the ones the exported statistics stood for.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from training.migrationnet import build_migrationnet


def _conv_initialisers(path: Path) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """(weight, bias) of each Conv node of the graph, in the graph's (topological = traced) order."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(path)).graph
    values = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    out = []
    for node in graph.node:
        if node.op_type == "Conv":
            weight = values[node.input[1]]
            bias = values[node.input[2]] if len(node.input) > 2 and node.input[2] else None
            out.append((weight, bias))
    return out


def _convs_in_execution_order(model: nn.Module, rows: int, cols: int) -> list[tuple[nn.Conv2d, nn.Module | None]]:
    """Each Conv2d as the forward pass runs it, with the BatchNorm2d that follows it in its Sequential (or None)."""
    following: dict[nn.Conv2d, nn.Module | None] = {}
    for module in model.modules():
        if isinstance(module, nn.Sequential):
            children = list(module)
            for a, b in zip(children, [*children[1:], None], strict=True):
                if isinstance(a, nn.Conv2d):
                    following[a] = b if isinstance(b, nn.BatchNorm2d) else None
    order: list[nn.Conv2d] = []
    hooks = [m.register_forward_hook(lambda mod, _i, _o: order.append(mod))  # type: ignore[arg-type]
             for m in model.modules() if isinstance(m, nn.Conv2d)]
    with torch.no_grad():
        model.eval()(torch.zeros(1, 1, rows, cols))
    for h in hooks:
        h.remove()
    return [(conv, following.get(conv)) for conv in order]


def migrationnet_from_onnx(path: Path, width: int = 8, rows: int = 128, cols: int = 128) -> nn.Module:
    """The PyTorch MigrationNet (probabilities wrapper) whose eval-mode output equals the ONNX model's."""
    model = build_migrationnet(width=width)
    convs = _convs_in_execution_order(model, rows, cols)
    weights = _conv_initialisers(path)
    if len(convs) != len(weights):
        raise ValueError(f"{path}: {len(weights)} convolutions in the graph, "
                         f"{len(convs)} in MigrationNet(width={width})")
    with torch.no_grad():
        for (conv, norm), (w, b) in zip(convs, weights, strict=True):
            if tuple(conv.weight.shape) != w.shape:
                raise ValueError(f"{path}: a convolution of shape {w.shape} where the net has "
                                 f"{tuple(conv.weight.shape)}")
            conv.weight.copy_(torch.from_numpy(np.array(w)))
            bias = torch.zeros(w.shape[0]) if b is None else torch.from_numpy(np.array(b))
            if norm is None:
                if conv.bias is None:
                    raise ValueError(f"{path}: a folded bias with nowhere to go")
                conv.bias.copy_(bias)
                continue
            assert isinstance(norm, nn.BatchNorm2d)
            assert norm.running_mean is not None and norm.running_var is not None
            norm.weight.fill_(1.0)
            norm.bias.copy_(bias)
            norm.running_mean.zero_()
            norm.running_var.fill_(1.0 - norm.eps)
    return model


def freeze_batch_norm(model: nn.Module) -> None:
    """Batch norms to eval mode (running statistics used, not updated); their scale and shift still train."""
    for module in model.modules():
        if isinstance(module, nn.BatchNorm2d):
            module.eval()


def check_parity(model: nn.Module, path: Path, seed: int = 0) -> float:
    """Largest |PyTorch − ONNX Runtime| probability on a random batch of two tiles."""
    import onnxruntime as ort

    x = np.random.default_rng(seed).standard_normal((2, 1, 128, 128)).astype(np.float32)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    expected = session.run(None, {session.get_inputs()[0].name: x})[0]
    model.eval()
    with torch.no_grad():
        got = model(torch.from_numpy(x)).numpy()
    return float(np.abs(got - expected).max())
