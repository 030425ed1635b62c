"""The report as a document: verdict rows, sections (figures, tables, images), the paper comparison,
and its two renderings, Markdown (`markdown.render`) and self-contained HTML (`html.render`).

Pure data → text, no artefact knowledge: `rxcomm.report` builds the sections from artefact summaries;
the `report` stage reads the files and writes both renderings.
"""
