"""Artefact I/O at the edges of the stages.

- ``files``: atomic write-then-rename (``NAME.part``)
- ``yaml_io``: YAML artefacts and config files (strict reading -> InputError(file, field)), summary YAML
- ``mcap_io``: MCAP time series with the envelope inside; writer, reader, recovery of killed writes
- ``trajectory``: the trajectory artefact (MCAP samples + summary YAML)
- ``validate``: pydantic validation errors -> InputError; kind/schema_version checks

May import: `rxcomm.schemas`, `rxcomm.errors`. The schemas never import this package (they are the
contract it reads and writes; docs/architecture.md).
"""
