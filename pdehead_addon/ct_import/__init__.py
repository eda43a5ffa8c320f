"""Step 1: CT import into a CTVolume (being split into one module per format; see :mod:`.dicom`)."""
from .dicom import CTImportWarning, SeriesInfo, list_series, load_ct

__all__ = ["load_ct", "list_series", "SeriesInfo", "CTImportWarning"]
