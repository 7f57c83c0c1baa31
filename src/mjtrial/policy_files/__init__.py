"""Trained policies from files (an ONNX graph and its contract).

- `file`: a policy file: its contract, the checks against the task and the graph,
  onnxruntime's session settings, the batch policy, the files it is made of.
- `onnx_data`: the files a graph loads beside itself (its external data), read from its
  protobuf.
- `check`: `mjtrial policy check FILE --task T`.
"""
