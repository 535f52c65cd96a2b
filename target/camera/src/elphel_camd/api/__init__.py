"""The REST API of the daemon."""

from elphel_camd.api.app import create_app

__all__ = ["create_app"]
