"""The V4L2 image path: raw formats, unpacking, the frame ring, streams, controls.

`formats` and `unpack` are pure; `node` is the one module that talks to a device (through
linuxpy, the optional ``v4l2`` extra); `synthetic` stands in for a node in tests and
benchmarks. The board that puts them together is `elphel_camd.boards.v4l2`.
"""
