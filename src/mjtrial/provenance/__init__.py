"""Provenance stamps: what produced an output file, carried inside the file itself.

:mod:`~mjtrial.provenance.stamp` builds a stamp (git state, library versions, platform,
hashes of the config slice and the inputs); :mod:`~mjtrial.provenance.formats` writes it into
each output format and reads it back, with a registry of readers by file suffix that other
modules add to (``.rrd`` from :mod:`mjtrial.recording`).
"""

from mjtrial.provenance.formats import (
    STAMP_KEY,
    MissingStampError,
    StampReader,
    is_folder_output,
    log_stamp_line,
    markdown_with_stamp,
    read_stamp,
    register_folder_reader,
    register_reader,
    write_figure,
    write_json,
    write_markdown,
    write_parquet,
    write_svg,
)
from mjtrial.provenance.stamp import (
    RECORDING_FOLDER_BLUEPRINT,
    RECORDING_FOLDER_STAMP,
    STAMP_VERSION,
    config_hash,
    file_sha256,
    git_state,
    is_recording_folder,
    is_stamp,
    library_versions,
    make_stamp,
    model_files,
    model_sha256,
    path_in_repo,
    platform_fingerprint,
    repo_relative,
)

__all__ = [
    "RECORDING_FOLDER_BLUEPRINT",
    "RECORDING_FOLDER_STAMP",
    "STAMP_KEY",
    "STAMP_VERSION",
    "MissingStampError",
    "StampReader",
    "is_folder_output",
    "log_stamp_line",
    "config_hash",
    "file_sha256",
    "git_state",
    "is_recording_folder",
    "is_stamp",
    "library_versions",
    "make_stamp",
    "markdown_with_stamp",
    "model_files",
    "model_sha256",
    "path_in_repo",
    "platform_fingerprint",
    "read_stamp",
    "register_folder_reader",
    "register_reader",
    "repo_relative",
    "write_figure",
    "write_json",
    "write_markdown",
    "write_parquet",
    "write_svg",
]
