"""The stock NC393 backend: a camera running Elphel's own firmware, reached directly.

``client`` (`NC393Client`), ``address`` (the ``nc393://`` URL), ``capture`` and ``frames``
(frames through imgsrv), ``model`` (a change checked against elphel-camd's parameter
model), ``parsedit`` and ``imgsrv`` (the two wire formats), ``http`` (one GET).
"""
