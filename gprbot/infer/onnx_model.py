"""An ONNX model and its model card: one onnxruntime session with fixed thread counts, checked inputs.

Every shipped model `models/NAME.onnx` has a card `models/NAME.json` (or `NAME.onnx.json`) written by
`tools/export_onnx.py`: name, sha256 of the ONNX file, inputs and outputs (name, shape, dtype, units),
normalisation, training data and metrics. The session refuses a model whose card does not match it,
so that a model retrained without re-exporting its card, or a truncated download, fails loudly.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import ModelError

_ORT_DTYPES: dict[str, np.dtype[Any]] = {
    "tensor(float)": np.dtype(np.float32),
    "tensor(double)": np.dtype(np.float64),
    "tensor(int64)": np.dtype(np.int64),
    "tensor(int32)": np.dtype(np.int32),
    "tensor(uint8)": np.dtype(np.uint8),
    "tensor(bool)": np.dtype(np.bool_),
}
_FIX = (
    "re-export it with tools/export_onnx.py, or set interpretation.method: classical"
    " / reconstruction.completion: geometric"
)


@dataclass(frozen=True)
class TensorSpec:
    """One input or output: name, shape (an int per fixed axis, a name per dynamic one) and dtype."""

    name: str
    shape: tuple[int | str, ...]
    dtype: np.dtype[Any]


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def card_path_for(path: Path) -> Path:
    """The model card of an ONNX file: `<path>.json` if it exists, else `<stem>.json` beside it."""
    beside = path.with_name(path.name + ".json")
    return beside if beside.exists() else path.with_suffix(".json")


def _dims(shape: Any) -> tuple[int | str, ...]:
    return tuple(d if isinstance(d, int) else str(d) for d in shape)


def _load_card(path: Path) -> dict[str, Any]:
    card_path = card_path_for(path)
    try:
        card = json.loads(card_path.read_text())
    except FileNotFoundError as exc:
        raise ModelError(f"model card {card_path} is missing; {_FIX}") from exc
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelError(f"model card {card_path} cannot be read ({exc}); {_FIX}") from exc
    if not isinstance(card, dict) or not {"name", "sha256", "inputs", "outputs"} <= card.keys():
        raise ModelError(f"model card {card_path} lacks name/sha256/inputs/outputs; {_FIX}")
    return card


class OnnxModel:
    """An ONNX model loaded with its card: `run(inputs)` → (outputs by name, seconds)."""

    def __init__(self, path: Path, *, threads: int = 2, expect_name: str | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"model file {path} is missing; {_FIX}")
        self.path = path
        self.card = _load_card(path)
        if expect_name is not None and self.card["name"] != expect_name:
            raise ModelError(f"{path} is the model {self.card['name']!r}, expected {expect_name!r}; check the path")
        if file_sha256(path) != self.card["sha256"]:
            raise ModelError(f"{path} does not match the sha256 in its model card (corrupt or replaced); {_FIX}")
        import onnxruntime as ort  # deferred: a gprbot without models never loads the runtime

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.log_severity_level = 3
        try:
            self._session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own untyped exceptions for bad files
            raise ModelError(f"onnxruntime cannot load {path} ({exc}); {_FIX}") from exc
        self.inputs = tuple(
            TensorSpec(i.name, _dims(i.shape), _ORT_DTYPES.get(i.type, np.dtype(object)))
            for i in self._session.get_inputs()
        )
        self.outputs = tuple(
            TensorSpec(o.name, _dims(o.shape), _ORT_DTYPES.get(o.type, np.dtype(object)))
            for o in self._session.get_outputs()
        )
        self._check_card_matches()
        self.warmup_s = self.run({s.name: np.zeros(self._example_shape(s), s.dtype) for s in self.inputs})[1]

    @property
    def name(self) -> str:
        """The model's name from its card."""
        return str(self.card["name"])

    def _check_card_matches(self) -> None:
        for kind, actual in (("inputs", self.inputs), ("outputs", self.outputs)):
            listed = self.card[kind]
            if [e.get("name") for e in listed] != [s.name for s in actual]:
                raise ModelError(
                    f"{self.path}: card {kind} {[e.get('name') for e in listed]} differ from the model's "
                    f"{[s.name for s in actual]}; {_FIX}"
                )
            for entry, spec in zip(listed, actual, strict=True):
                shape = tuple(entry.get("shape", ()))
                same = len(shape) == len(spec.shape) and all(
                    not isinstance(c, int) or not isinstance(m, int) or c == m
                    for c, m in zip(shape, spec.shape, strict=True)
                )
                if not same or np.dtype(entry.get("dtype", "")) != spec.dtype:
                    raise ModelError(
                        f"{self.path}: {kind[:-1]} {spec.name!r} is {spec.shape} {spec.dtype} in the model but "
                        f"{shape} {entry.get('dtype')} in the card; {_FIX}"
                    )

    @staticmethod
    def _example_shape(spec: TensorSpec) -> tuple[int, ...]:
        return tuple(d if isinstance(d, int) else 1 for d in spec.shape)

    def run(self, inputs: Mapping[str, NDArray[Any]]) -> tuple[dict[str, NDArray[Any]], float]:
        """Run the model on named inputs; returns the outputs by name and the run's wall time (s)."""
        names = {s.name for s in self.inputs}
        if set(inputs) != names:
            raise ModelError(f"{self.name}: inputs {sorted(inputs)} given, the model takes {sorted(names)}")
        feed: dict[str, NDArray[Any]] = {}
        for spec in self.inputs:
            value = np.asarray(inputs[spec.name])
            if value.dtype != spec.dtype:
                raise ModelError(f"{self.name}: input {spec.name!r} must be {spec.dtype}, got {value.dtype}")
            fits = value.ndim == len(spec.shape) and all(
                not isinstance(d, int) or d == n for d, n in zip(spec.shape, value.shape, strict=True)
            )
            if not fits:
                raise ModelError(f"{self.name}: input {spec.name!r} must have shape {spec.shape}, got {value.shape}")
            feed[spec.name] = np.ascontiguousarray(value)
        start = time.perf_counter()
        results = self._session.run(None, feed)
        elapsed = time.perf_counter() - start
        return {s.name: np.asarray(r) for s, r in zip(self.outputs, results, strict=True)}, elapsed
