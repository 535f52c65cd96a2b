SUMMARY = "Camera daemon for Elphel-style multi-sensor boards"
DESCRIPTION = "elphel-camd programs image sensors over Linux I2C and serves \
               their frame parameters, registers and captures over a \
               token-protected REST API."
# No HOMEPAGE or BUGTRACKER: the elphel-rig repository has no public address yet
# (the layer's .oelint.cfg suppresses those two checks, and tests/yocto requires
# HOMEPAGE on every recipe of third-party software).
SECTION = "multimedia"
CVE_PRODUCT = "elphel-camd"
# The repository's Apache License 2.0 text, copied into the daemon's own folder
# (target/camera/LICENSE, the same bytes as the repository's LICENSE) so the
# daemon's source tree and its sdist carry it.
LICENSE = "Apache-2.0"
LIC_FILES_CHKSUM = "file://LICENSE;md5=3b83ef96387f14655fc854ddc3c6bd57"

# The source is this repository's own checkout, not a download: the layer lives at
# yocto/meta-elphel, so the repository's target/ folder is four levels above this
# recipe's folder and file://camera is target/camera (the daemon's pyproject).
# Editing the daemon changes the fetch checksum, so the next build rebuilds it.
# nooelint: oelint.vars.fileextrapaths,oelint.vars.outofcontext - the recipe's own source tree
FILESEXTRAPATHS:prepend := "${THISDIR}/../../../../target:"

SRC_URI = "file://camera \
           file://60-elphel-camd-i2c.rules \
           file://config.json \
           file://elphel-camd.default \
           file://elphel-camd.init \
           file://elphel-camd.service \
"

S = "${UNPACKDIR}/camera"

inherit python_setuptools_build_meta systemd update-rc.d useradd

# The one place that names how the daemon is started: the systemd unit and the
# SysV script are templates filled in from these two values in do_install.
ELPHEL_CAMD_BOARD ?= "i2c"
ELPHEL_CAMD_CONFIG = "${sysconfdir}/elphel-camd/config.json"

USERADD_PACKAGES = "${PN}"
GROUPADD_PARAM:${PN} = "--system i2c"
USERADD_PARAM:${PN} = "--system --user-group --groups i2c --no-create-home \
                       --home-dir /nonexistent --shell ${base_bindir}/false elphel-camd"

SYSTEMD_SERVICE:${PN} = "elphel-camd.service"
INITSCRIPT_NAME = "elphel-camd"
INITSCRIPT_PARAMS = "defaults 90 10"

do_install:append() {
    install -d ${D}${sysconfdir}/elphel-camd ${D}${sysconfdir}/default
    install -m 0644 ${UNPACKDIR}/config.json ${D}${ELPHEL_CAMD_CONFIG}
    # Holds ELPHEL_CAMD_TOKEN: readable by root only (systemd and the init script
    # read it before dropping to the daemon's user).
    install -m 0600 ${UNPACKDIR}/elphel-camd.default ${D}${sysconfdir}/default/elphel-camd

    install -d ${D}${nonarch_base_libdir}/udev/rules.d
    install -m 0644 ${UNPACKDIR}/60-elphel-camd-i2c.rules ${D}${nonarch_base_libdir}/udev/rules.d/

    if ${@bb.utils.contains('DISTRO_FEATURES', 'systemd', 'true', 'false', d)}; then
        install -d ${D}${systemd_system_unitdir}
        install -m 0644 ${UNPACKDIR}/elphel-camd.service ${D}${systemd_system_unitdir}/
    fi
    if ${@bb.utils.contains('DISTRO_FEATURES', 'sysvinit', 'true', 'false', d)}; then
        install -d ${D}${sysconfdir}/init.d
        install -m 0755 ${UNPACKDIR}/elphel-camd.init ${D}${sysconfdir}/init.d/elphel-camd
    fi
    for f in ${D}${systemd_system_unitdir}/elphel-camd.service ${D}${sysconfdir}/init.d/elphel-camd; do
        [ -e "$f" ] || continue
        sed -i -e 's|@BINDIR@|${bindir}|g' \
               -e 's|@SYSCONFDIR@|${sysconfdir}|g' \
               -e 's|@ELPHEL_CAMD_BOARD@|${ELPHEL_CAMD_BOARD}|g' \
               -e 's|@ELPHEL_CAMD_CONFIG@|${ELPHEL_CAMD_CONFIG}|g' \
               "$f"
    done
}

FILES:${PN} += "${nonarch_base_libdir}/udev/rules.d"
CONFFILES:${PN} = "${ELPHEL_CAMD_CONFIG} ${sysconfdir}/default/elphel-camd"

# pydantic-settings is not imported yet; the daemon's settings work adds it.
RDEPENDS:${PN} = "\
    python3-core \
    python3-fastapi \
    python3-json \
    python3-logging \
    python3-numpy \
    python3-pillow \
    python3-pydantic \
    python3-pydantic-settings \
    python3-smbus2 \
    python3-threading \
    python3-tifffile \
    python3-uvicorn \
"
