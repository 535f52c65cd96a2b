SUMMARY = "Settings management using pydantic"
DESCRIPTION = "pydantic-settings loads typed settings from environment \
               variables, dotenv files and secret files into pydantic models."
HOMEPAGE = "https://github.com/pydantic/pydantic-settings"
BUGTRACKER = "https://github.com/pydantic/pydantic-settings/issues"
SECTION = "devel/python"
LICENSE = "MIT"
LIC_FILES_CHKSUM = "file://LICENSE;md5=9adde1a30a7e74a03e57e456551c19ae"

PYPI_PACKAGE = "pydantic_settings"
SRC_URI[sha256sum] = "694b793e84f766ba76a90ebdefc01d0a9a045dab0382bee70393da93712ad117"

inherit pypi python_hatchling

RDEPENDS:${PN} = "\
    python3-asyncio \
    python3-core \
    python3-json \
    python3-pydantic \
    python3-python-dotenv \
    python3-typing-inspection \
"

BBCLASSEXTEND = "native nativesdk"
