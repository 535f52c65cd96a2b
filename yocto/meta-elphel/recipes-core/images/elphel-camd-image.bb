SUMMARY = "Minimal camera image running the elphel-camd daemon"
DESCRIPTION = "A console-only image with an SSH server and elphel-camd started \
               at boot by systemd or SysV init, whichever the distro selects."
SECTION = "images"
LICENSE = "MIT"

inherit core-image

IMAGE_FEATURES += "ssh-server-dropbear"

IMAGE_INSTALL = "\
    packagegroup-core-boot \
    packagegroup-elphel-camd \
    ${CORE_IMAGE_EXTRA_INSTALL} \
"
