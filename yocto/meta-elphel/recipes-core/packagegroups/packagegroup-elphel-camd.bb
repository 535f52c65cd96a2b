SUMMARY = "elphel-camd and the tools to inspect its I2C buses on the camera"
DESCRIPTION = "Everything a camera image needs to run the elphel-camd daemon."
SECTION = "base"
LICENSE = "MIT"

inherit packagegroup

RDEPENDS:${PN} = "\
    elphel-camd \
    i2c-tools \
"
