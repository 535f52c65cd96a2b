SUMMARY = "Read and write TIFF files"
DESCRIPTION = "tifffile stores numpy arrays in TIFF files and reads image and \
               metadata from TIFF-like files; elphel-camd writes its 16-bit captures with it."
HOMEPAGE = "https://www.cgohlke.com"
BUGTRACKER = "https://github.com/cgohlke/tifffile/issues"
SECTION = "devel/python"
LICENSE = "BSD-3-Clause"
LIC_FILES_CHKSUM = "file://LICENSE;md5=228837c3a3eda31fb28d51e82dd7a225"

SRC_URI[sha256sum] = "d9a1266bed6f2ee1dd0abde2018a38b4f8b2935cb843df381d70ac4eac5458b7"

inherit pypi python_setuptools_build_meta

RDEPENDS:${PN} = "\
    python3-compression \
    python3-core \
    python3-datetime \
    python3-json \
    python3-logging \
    python3-mmap \
    python3-numpy \
    python3-threading \
"

BBCLASSEXTEND = "native nativesdk"
