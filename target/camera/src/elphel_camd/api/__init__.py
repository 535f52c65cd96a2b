"""The REST API of the daemon.

`app` builds it (`create_app`), `routes/` holds one router per resource group, `deps` what
the routes are given (the service, the token checks), `errors` the problem answers,
`middleware` the body limit, `models` the request and answer schemas, `tiff` the streamed
TIFF writer.
"""

from elphel_camd.api.app import create_app

__all__ = ["create_app"]
