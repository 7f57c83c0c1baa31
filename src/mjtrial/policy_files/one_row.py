"""A policy file's graph called on one row at a time, its inputs and outputs bound once to
arrays of one row (onnxruntime's `io_binding`): the replay's path (`OnnxPolicy.alone`). A call
costs about half of a `session.run` (8 µs against 14 for the shipped MLPs' size), with the
same kernels on the same row, so the same bits."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import onnxruntime


class OneRow:
    """The graph on one row of its input, its recurrent state carried from call to call.

    Args:
      session: the graph's session.
      contract: its contract (`file.Contract`: the input's name, the recurrent states).
      n_inputs: the input's width.
      outputs, widths: every output read (the action first, then each recurrent state's, in
        the same order).
    """

    def __init__(
        self,
        session: onnxruntime.InferenceSession,
        contract: Any,
        n_inputs: int,
        outputs: Sequence[str],
        widths: Sequence[int],
    ) -> None:
        self.session = session
        self.row = np.empty((1, n_inputs), dtype=np.float32)
        self.state = {r.input: np.zeros((1, r.size), dtype=np.float32) for r in contract.recurrent}
        self.answers = [np.empty((1, width), dtype=np.float32) for width in widths]
        self.binding = session.io_binding()
        for name, array in [(contract.input, self.row), *self.state.items()]:
            self.binding.bind_cpu_input(name, array)  # the arrays' memory, read at each call
        for name, array in zip(outputs, self.answers, strict=True):
            self.binding.bind_output(name, "cpu", 0, np.float32, array.shape, array.ctypes.data)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The action (n_outputs,) for row `x`; the recurrent state moves on. Raises
        onnxruntime's error where an output has another shape than one row's (the state is
        then as it was before the call)."""
        self.row[0] = x
        self.session.run_with_iobinding(self.binding)
        for array, value in zip(self.state.values(), self.answers[1:], strict=True):
            array[...] = value
        return self.answers[0][0]
