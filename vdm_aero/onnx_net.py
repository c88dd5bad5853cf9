"""The one door to onnxruntime: the correction net at run time.

Single-sample calls are dominated by onnxruntime's per-call overhead, not by the 4×40 net. Measured
on the 2-core dev machine (median of 20,000 calls, 10 inputs, 4×40 ReLU net): ``InferenceSession.run``
≈ 4.8 µs, ``run`` with reused ``RunOptions`` ≈ 4.3 µs, io-binding with input/output bound once to
our own numpy buffers ≈ 3.2 µs — but ≈ 27 µs if ``RunOptions`` are passed to ``run_with_iobinding``;
numpy evaluation of the same net ≈ 7.9 µs. So :meth:`predict_one`
uses io-binding over preallocated buffers and :meth:`predict_batch` uses ``run``. ``vdm-aero bench
aero`` re-measures both ways on the machine at hand.

One :class:`OnnxCorrection` per thread: ``predict_one`` writes into shared buffers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort

from vdm_aero._typing import F64Array, FloatArray
from vdm_aero.errors import ModelError


class OnnxCorrection:
    """A correction net ``(K, n_in) float32 → (K, n_out) float32`` loaded from a self-contained ONNX file."""

    def __init__(self, path: str | Path, *, threads: int = 1) -> None:
        opts = ort.SessionOptions()
        # tiny nets: thread pools cost more than they save, and the EKF owns the other core
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3  # errors only: a refused model is our one-line error, not onnxruntime's banner
        try:
            self._sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 — onnxruntime's pybind11 errors share no narrower base
            raise ModelError(f"{path}: not a loadable ONNX model ({type(e).__name__})") from None
        inputs, outputs = self._sess.get_inputs(), self._sess.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise ModelError(f"{path}: expected one input and one output, got {len(inputs)} and {len(outputs)}")
        self.input_name, self.output_name = inputs[0].name, outputs[0].name
        self.n_in = _static_dim(inputs[0].shape, path, "input")
        self.n_out = _static_dim(outputs[0].shape, path, "output")
        self._x1 = np.zeros((1, self.n_in), dtype=np.float32)
        self._y1 = np.zeros((1, self.n_out), dtype=np.float32)
        self._binding = self._sess.io_binding()
        self._binding.bind_ortvalue_input(self.input_name, ort.OrtValue.ortvalue_from_numpy(self._x1))
        self._binding.bind_ortvalue_output(self.output_name, ort.OrtValue.ortvalue_from_numpy(self._y1))
        self._run_options = ort.RunOptions()

    def predict_one(self, x: FloatArray) -> F64Array:
        """One sample (n_in,) → (n_out,) float64, via io-binding (no per-call allocation in onnxruntime)."""
        self._x1[0, :] = x
        self._sess.run_with_iobinding(self._binding)  # no RunOptions here: measured +25 µs per call
        return self._y1[0].astype(np.float64)

    def predict_one_run(self, x: FloatArray) -> F64Array:
        """One sample through ``InferenceSession.run`` (kept for the latency benchmark)."""
        self._x1[0, :] = x
        out = self._sess.run([self.output_name], {self.input_name: self._x1}, self._run_options)[0]
        return np.asarray(out[0], dtype=np.float64)

    def predict_batch(self, x: FloatArray) -> F64Array:
        """(K, n_in) → (K, n_out) float64."""
        xb = np.ascontiguousarray(np.atleast_2d(x), dtype=np.float32)
        out = self._sess.run([self.output_name], {self.input_name: xb}, self._run_options)[0]
        return np.asarray(out, dtype=np.float64)


def _static_dim(shape: list[object], path: str | Path, what: str) -> int:
    if len(shape) != 2 or not isinstance(shape[1], int):
        raise ModelError(f"{path}: {what} must have shape (batch, n) with a fixed n, got {shape}")
    return int(shape[1])
