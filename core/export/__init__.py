"""Export for engines: the maths behind baking ShapeSpace rigs into data glTF, FBX and Alembic carry.

- :mod:`.weights` — split / rescale a key whose weights leave [0, 1] (importers clamp), exact to float
  precision;
- :mod:`.frames` — which frames to bake (the actions' full range, not the scene's);
- :mod:`.formats` — the formats, what each carries, checks on the output path;
- :mod:`.compare` — round-trip measures (vertex matching, error per frame relative to the size);
- :mod:`.farm` — farm batches: chunks of takes and the merged per-take reports;
- :mod:`.report` — the export report.
"""
from .compare import match_vertices, roundtrip_error
from .farm import FarmSummary, chunk, merge_take_reports, read_take_report, take_stem
from .formats import FORMATS, ExportFormat, check_format, check_output_path, format_of
from .frames import MAX_FRAMES, export_range, sample_frames
from .report import BakedObject, ExportReport
from .weights import NEGATIVE_SUFFIX, WeightPart, recombine, split_weights, weight_range

__all__ = [
    "NEGATIVE_SUFFIX", "WeightPart", "split_weights", "recombine", "weight_range",
    "MAX_FRAMES", "export_range", "sample_frames",
    "FORMATS", "ExportFormat", "check_format", "check_output_path", "format_of",
    "match_vertices", "roundtrip_error",
    "FarmSummary", "chunk", "merge_take_reports", "read_take_report", "take_stem",
    "BakedObject", "ExportReport",
]
