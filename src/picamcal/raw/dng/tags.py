"""The numbers a DNG is made of: TIFF 6.0, TIFF/EP, EXIF 2.32 and DNG 1.4 tag codes, field types and values.

The reader (:mod:`~picamcal.raw.dng.reader`) and the writer (:mod:`~picamcal.raw.dng.writer`) both take them from
here.
"""

from __future__ import annotations

import struct

# TIFF 6.0 / TIFF-EP / EXIF 2.32 / DNG 1.4 tag codes.
NEW_SUBFILE_TYPE, IMAGE_WIDTH, IMAGE_LENGTH, BITS_PER_SAMPLE, COMPRESSION = 254, 256, 257, 258, 259
PHOTOMETRIC, IMAGE_DESCRIPTION, MAKE, MODEL, STRIP_OFFSETS = 262, 270, 271, 272, 273
ORIENTATION, SAMPLES_PER_PIXEL, ROWS_PER_STRIP, STRIP_BYTE_COUNTS = 274, 277, 278, 279
PLANAR_CONFIGURATION, SOFTWARE, DATE_TIME = 284, 305, 306
TILE_WIDTH, TILE_LENGTH, TILE_OFFSETS, TILE_BYTE_COUNTS, SUB_IFDS = 322, 323, 324, 325, 330
CFA_REPEAT_DIM, CFA_PATTERN, EXIF_IFD = 33421, 33422, 34665
EXPOSURE_TIME, ISO, EXIF_VERSION, DATE_TIME_ORIGINAL = 33434, 34855, 36864, 36867
OFFSET_TIME, OFFSET_TIME_ORIGINAL = 36880, 36881
DNG_VERSION, DNG_BACKWARD, UNIQUE_MODEL, CFA_PLANE_COLOR, CFA_LAYOUT = 50706, 50707, 50708, 50710, 50711
BLACK_REPEAT_DIM, BLACK_LEVEL, WHITE_LEVEL = 50713, 50714, 50717
FILL_ORDER, PREDICTOR, SAMPLE_FORMAT = 266, 317, 339
LINEARIZATION_TABLE, BLACK_DELTA_H, BLACK_DELTA_V, ACTIVE_AREA, MASKED_AREAS = 50712, 50715, 50716, 50829, 50830
COLOR_MATRIX1, AS_SHOT_NEUTRAL, ILLUMINANT1, FORWARD_MATRIX1 = 50721, 50728, 50778, 50964
BASELINE_EXPOSURE, OPCODE_LIST2 = 50730, 51009

TAG_NAMES = {
    NEW_SUBFILE_TYPE: "NewSubFileType", IMAGE_WIDTH: "ImageWidth", IMAGE_LENGTH: "ImageLength",
    BITS_PER_SAMPLE: "BitsPerSample", COMPRESSION: "Compression", PHOTOMETRIC: "PhotometricInterpretation",
    IMAGE_DESCRIPTION: "ImageDescription", MAKE: "Make", MODEL: "Model", STRIP_OFFSETS: "StripOffsets",
    SAMPLES_PER_PIXEL: "SamplesPerPixel", ROWS_PER_STRIP: "RowsPerStrip", STRIP_BYTE_COUNTS: "StripByteCounts",
    PLANAR_CONFIGURATION: "PlanarConfiguration", TILE_WIDTH: "TileWidth", TILE_LENGTH: "TileLength",
    TILE_OFFSETS: "TileOffsets", TILE_BYTE_COUNTS: "TileByteCounts", SUB_IFDS: "SubIFDs",
    CFA_REPEAT_DIM: "CFARepeatPatternDim", CFA_PATTERN: "CFAPattern", EXIF_IFD: "ExifIFD",
    EXPOSURE_TIME: "ExposureTime", ISO: "ISOSpeedRatings", DATE_TIME_ORIGINAL: "DateTimeOriginal",
    DNG_VERSION: "DNGVersion", UNIQUE_MODEL: "UniqueCameraModel", CFA_PLANE_COLOR: "CFAPlaneColor",
    CFA_LAYOUT: "CFALayout", BLACK_REPEAT_DIM: "BlackLevelRepeatDim", BLACK_LEVEL: "BlackLevel",
    WHITE_LEVEL: "WhiteLevel", COLOR_MATRIX1: "ColorMatrix1", AS_SHOT_NEUTRAL: "AsShotNeutral",
    ILLUMINANT1: "CalibrationIlluminant1", FORWARD_MATRIX1: "ForwardMatrix1",
    BASELINE_EXPOSURE: "BaselineExposure", OPCODE_LIST2: "OpcodeList2", FILL_ORDER: "FillOrder",
    PREDICTOR: "Predictor", SAMPLE_FORMAT: "SampleFormat", LINEARIZATION_TABLE: "LinearizationTable",
    BLACK_DELTA_H: "BlackLevelDeltaH", BLACK_DELTA_V: "BlackLevelDeltaV", ACTIVE_AREA: "ActiveArea",
    MASKED_AREAS: "MaskedAreas",
}  # fmt: skip

# TIFF field types (TIFF 6.0 section 2, and IFD of TIFF technical note 1), the struct code of one value (a
# rational is two) and their names for messages.
BYTE, ASCII, SHORT, LONG, RATIONAL, SBYTE, UNDEFINED = 1, 2, 3, 4, 5, 6, 7
SSHORT, SLONG, SRATIONAL, FLOAT, DOUBLE, IFD = 8, 9, 10, 11, 12, 13
STRUCT = {
    BYTE: "B", ASCII: "B", SHORT: "H", LONG: "I", RATIONAL: "II", SBYTE: "b", UNDEFINED: "B",
    SSHORT: "h", SLONG: "i", SRATIONAL: "ii", FLOAT: "f", DOUBLE: "d", IFD: "I",
}  # fmt: skip
TYPE_SIZE = {kind: struct.calcsize("<" + code) for kind, code in STRUCT.items()}
TYPE_NAMES = {
    BYTE: "BYTE", ASCII: "ASCII", SHORT: "SHORT", LONG: "LONG", RATIONAL: "RATIONAL", SBYTE: "SBYTE",
    UNDEFINED: "UNDEFINED", SSHORT: "SSHORT", SLONG: "SLONG", SRATIONAL: "SRATIONAL", FLOAT: "FLOAT",
    DOUBLE: "DOUBLE", IFD: "IFD",
}  # fmt: skip

#: CFAPattern's colour codes (with CFAPlaneColor 0 1 2), PhotometricInterpretation's mosaic and demosaiced values.
CFA_CODES = {"R": 0, "G": 1, "B": 2}
CFA_PHOTOMETRIC, LINEAR_RAW = 32803, 34892
D65 = 21  # EXIF LightSource / DNG CalibrationIlluminant code

#: The key of picamcal's own record, ``{"picamcal": {...}}``, in ImageDescription.
METADATA_KEY = "picamcal"
#: RawImage metadata keys that the colour tags are read into: the tags are the truth, a JSON copy would go stale.
COLOUR_KEYS = ("as_shot_neutral", "color_matrix1", "forward_matrix1", "calibration_illuminant1")
