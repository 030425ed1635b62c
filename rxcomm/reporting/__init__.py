"""The commissioning report: the document, its sections and its verdict.

- `document`: the document model (verdict rows, sections with figures, tables and images); the paper
  comparison is built from every figure that carries a paper value;
- `markdown`, `html`: its two renderings (report.md; report.html, self-contained);
- `calibration`, `identification`, `runs`: each stage's section from its artefact's summary (paper
  §3, §4, §5 and §2.3), `values` how they write a number;
- `targets`: the verdict rows, acceptance criteria first, then the stage targets.

Pure functions over plain mappings read from the artefacts: the `report` stage reads the files and
writes both renderings. Imports only `rxcomm.reporting` itself.
"""
