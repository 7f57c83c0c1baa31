"""The files an ONNX graph loads beside itself: its external data (tensors stored in a separate
file that the graph names by a path relative to its own folder).

onnxruntime reads them when it opens the graph, so a run's result depends on them as on the
`.onnx` file: they are inputs of the jobs that run the graph, stamped and copied with it
(`mjtrial.policy_files.file.policy_file_paths`).

The graph is read here at the protobuf wire level, not with the `onnx` package: that package is
not a dependency of a run (onnxruntime is), and its `onnx.load` would hold a 400 MB graph's
weights in the memory of Snakemake's process, which asks for a policy's files at every job; the
walk below skips every tensor's bytes. It reads the messages onnxruntime reads tensors from
(onnx.proto3): the graph's initializers and sparse initializers, every node attribute's tensors
and subgraphs (If, Loop, Scan), and the model's functions; `tests/test_policy_data.py` checks
it against `onnx`'s own list on graphs with external data. Each tensor says whether it is an
initializer of the main graph: onnxruntime 1.31.1 looks for the others' data in the working
folder, not the graph's, so `policy_file.data_files` refuses them.
"""

from __future__ import annotations

import mmap
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

# Field numbers of onnx.proto3 (onnx 1.23.2), by message.
_MODEL_GRAPH, _MODEL_FUNCTIONS = 7, 25
_GRAPH_NODE, _GRAPH_INITIALIZER, _GRAPH_SPARSE_INITIALIZER = 1, 5, 15
_NODE_ATTRIBUTE = 5
_FUNCTION_NODE = 7
_ATTRIBUTE_T, _ATTRIBUTE_G, _ATTRIBUTE_TENSORS, _ATTRIBUTE_GRAPHS = 5, 6, 10, 11
_ATTRIBUTE_SPARSE_TENSOR, _ATTRIBUTE_SPARSE_TENSORS = 22, 23
_SPARSE_VALUES, _SPARSE_INDICES = 1, 2
_TENSOR_NAME, _TENSOR_EXTERNAL_DATA, _TENSOR_DATA_LOCATION = 8, 13, 14
_ENTRY_KEY, _ENTRY_VALUE = 1, 2
_EXTERNAL = 1  # TensorProto.DataLocation.EXTERNAL
_LENGTH_DELIMITED = 2

_Span = tuple[int, int]


@dataclass(frozen=True)
class ExternalTensor:
    """A tensor whose data is in another file: `location`, relative to the graph's folder."""

    name: str
    location: str
    main: bool  # an initializer of the main graph, not a node attribute's nor a subgraph's


class GraphFormatError(ValueError):
    """Bytes that are not a well-formed ONNX protobuf (onnxruntime then says why it cannot
    load the file)."""


def external_data(onnx_file: str | Path) -> tuple[ExternalTensor, ...]:
    """The tensors of a graph whose data is in other files, in the file's order; () for a graph
    that holds all its tensors. Raises `GraphFormatError` for bytes that are not an ONNX
    model."""
    if Path(onnx_file).stat().st_size == 0:
        return ()
    found = []
    with open(onnx_file, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
        with memoryview(mapped) as buf:
            try:
                for tensor, main in _model_tensors(buf, (0, len(buf))):
                    location, name = _external_location(buf, tensor)
                    if location is not None:
                        found.append(ExternalTensor(name, location, main))
            except (IndexError, GraphFormatError) as err:
                problem = str(err) if isinstance(err, GraphFormatError) else "truncated"
                raise GraphFormatError(f"{onnx_file}: not an ONNX model ({problem})") from None
    return tuple(found)


def _model_tensors(buf: memoryview, model: _Span) -> Iterator[tuple[_Span, bool]]:
    """Every tensor of the model: (its span, whether it is an initializer of the main graph)."""
    for field, span in _messages(buf, model):
        if field == _MODEL_GRAPH:
            yield from _graph_tensors(buf, span, main=True)
        elif field == _MODEL_FUNCTIONS:
            for inner, node in _messages(buf, span):
                if inner == _FUNCTION_NODE:
                    yield from _node_tensors(buf, node)


def _graph_tensors(buf: memoryview, graph: _Span, *, main: bool) -> Iterator[tuple[_Span, bool]]:
    for field, span in _messages(buf, graph):
        if field == _GRAPH_INITIALIZER:
            yield span, main
        elif field == _GRAPH_SPARSE_INITIALIZER:
            yield from ((t, main) for t in _sparse_tensors(buf, span))
        elif field == _GRAPH_NODE:
            yield from _node_tensors(buf, span)


def _node_tensors(buf: memoryview, node: _Span) -> Iterator[tuple[_Span, bool]]:
    for field, attribute in _messages(buf, node):
        if field != _NODE_ATTRIBUTE:
            continue
        for inner, span in _messages(buf, attribute):
            if inner in (_ATTRIBUTE_T, _ATTRIBUTE_TENSORS):
                yield span, False
            elif inner in (_ATTRIBUTE_G, _ATTRIBUTE_GRAPHS):
                yield from _graph_tensors(buf, span, main=False)
            elif inner in (_ATTRIBUTE_SPARSE_TENSOR, _ATTRIBUTE_SPARSE_TENSORS):
                yield from ((t, False) for t in _sparse_tensors(buf, span))


def _sparse_tensors(buf: memoryview, sparse: _Span) -> Iterator[_Span]:
    for field, span in _messages(buf, sparse):
        if field in (_SPARSE_VALUES, _SPARSE_INDICES):
            yield span


def _external_location(buf: memoryview, tensor: _Span) -> tuple[str | None, str]:
    """A tensor's external data location, or None when its data is in the graph (onnxruntime
    reads `external_data` only where `data_location` is EXTERNAL)."""
    external, location, name = False, None, ""
    for field, wire, value in _fields(buf, tensor):
        if field == _TENSOR_DATA_LOCATION and wire == 0:
            external = value == _EXTERNAL
        elif field == _TENSOR_NAME and wire == _LENGTH_DELIMITED:
            name = _text(buf, value)
        elif field == _TENSOR_EXTERNAL_DATA and wire == _LENGTH_DELIMITED:
            entry = {f: _text(buf, v) for f, w, v in _fields(buf, value) if w == _LENGTH_DELIMITED}
            if entry.get(_ENTRY_KEY) == "location":
                location = entry.get(_ENTRY_VALUE, "")
    return (location if external else None), name


def _messages(buf: memoryview, span: _Span) -> Iterator[tuple[int, _Span]]:
    """The length-delimited fields of a message: (field number, span of its bytes)."""
    for field, wire, value in _fields(buf, span):
        if wire == _LENGTH_DELIMITED:
            yield field, value


def _fields(buf: memoryview, span: _Span) -> Iterator[tuple[int, int, object]]:
    """A message's fields in wire order: (field number, wire type, value): a varint's value,
    a length-delimited field's span, None for fixed-width ones (skipped)."""
    pos, end = span
    while pos < end:
        key, pos = _varint(buf, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == _LENGTH_DELIMITED:
            size, pos = _varint(buf, pos)
            value, pos = (pos, pos + size), pos + size
        elif wire in (1, 5):
            value, pos = None, pos + (8 if wire == 1 else 4)
        else:
            raise GraphFormatError(f"wire type {wire} at byte {pos}; not an ONNX protobuf")
        if pos > end:
            raise GraphFormatError(f"a field runs past its message's end at byte {end}")
        yield field, wire, value


def _varint(buf: memoryview, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if byte < 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise GraphFormatError(f"a varint longer than 10 bytes at byte {pos}")


def _text(buf: memoryview, span: _Span) -> str:
    return bytes(buf[span[0] : span[1]]).decode("utf-8", errors="replace")
