"""Tile processor: per-tile sub-pixel disparity of quad images by CLT-domain phase correlation.

Modules: ``clt`` (the transform, its inverse and phase rotation), ``bayer`` (colour
lattices and weights), ``geometry`` (camera positions, pairs, tile placement),
``correlation`` (pair products, normalisation, correlation profiles and their maximum),
``spectra`` (the fast per-camera transform used in production), ``kernels`` (aberration
correction), ``processor`` (passes over all tiles), ``texture`` (inverse-CLT images and
RGBA textures), ``io`` (quad directories, DSI and ML_DATA files), ``cli``
(``elphel tp``). See docs/tile-processor.md.
"""
