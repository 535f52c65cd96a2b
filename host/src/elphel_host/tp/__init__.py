"""Tile processor: per-tile sub-pixel disparity of quad images by CLT-domain phase correlation.

Modules: ``clt`` (the transform: ``clt.transform`` the definition, ``clt.batch`` the
production path, ``clt.reference`` the lattice transform it is tested against),
``bayer`` (colour lattices and weights), ``geometry`` (camera positions, pairs, tile
placement), ``correlation`` (pair products, normalisation, correlation profiles and their
maximum), ``kernels`` (aberration correction), ``config`` (``TpConfig``), ``images``
(``QuadImages``), ``pipeline`` (one pass over all tiles), ``processor`` (the passes: the
DSI), ``texture`` (inverse-CLT images and RGBA textures), ``io`` (the quad directory
format), ``dsi`` (DSI and ML_DATA files), ``capture``, ``trigger`` and ``layout`` (taking a
quad set from a camera), ``cli`` (``elphel tp``). See docs/tile-processor.md.
"""
