"""Artefact I/O at the edges of the stages.

- ``files``: sha256 of inputs, atomic write-then-rename (``NAME.part``)
- ``yaml_io``: YAML artefacts and config files (strict reading -> InputError(file, field)), summary YAML
- ``mcap_io``: MCAP time series with the envelope inside; writer, reader, recovery of killed writes
- ``validate``: pydantic validation errors -> InputError; kind/schema_version checks
- ``plain``: numpy -> plain Python for YAML/JSON

Import the submodules directly; this package imports nothing so that ``rxcomm.schemas`` can use
``files``/``plain`` without an import cycle.
"""
