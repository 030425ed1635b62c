"""Artefact I/O at the edges of the stages.

- ``files``: atomic write-then-rename (``NAME.part``)
- ``yaml_io``: YAML artefacts and config files (strict reading -> InputError(file, field)), summary YAML
- ``mcap_format``: the MCAP layout (epoch time origin, protobuf column blocks, envelope records)
- ``mcap_io``: the MCAP writer (re-exports the reader); ``mcap_read``: reader, recovery of killed writes
- ``foxglove``: Foxglove's well-known schemas (FrameTransforms, PoseInFrame) and their messages
- ``csv_export``: trajectory and run-log CSV exports and their readers
- ``trajectory``: the trajectory artefact (MCAP samples + summary YAML)
- ``validate``: pydantic validation errors -> InputError; kind/schema_version checks

May import: `rxcomm.schemas`, `rxcomm.errors`. The schemas never import this package (they are the
contract it reads and writes; docs/architecture.md).
"""
