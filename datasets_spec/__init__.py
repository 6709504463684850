"""The dockbench dataset contract, imported by both the generator and the evaluator.

- ``FORMAT.md`` and ``LOCALIZER_PROTOCOL.md``: the format and the external-localizer protocol;
- ``*.schema.json``: JSON Schemas of ``manifest.json`` and of one ``frames.jsonl`` line;
- :mod:`datasets_spec.io`: one place that reads and writes each file of a dataset, and hashes them.

Never imports bpy, blendgen or evalkit.
"""

from datasets_spec.io import (  # noqa: F401
    DEFAULT_D_MIN_REL_M,
    FORMAT_NAME,
    MANIFEST,
    SPEC_VERSION,
    SUPPORTED_SPEC_VERSIONS,
    DatasetError,
    content_hash,
    dataset_files,
    load_manifest,
    load_schema,
    save_json_atomic,
    sha256_file,
)
