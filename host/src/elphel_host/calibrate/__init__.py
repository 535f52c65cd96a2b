"""Camera and rig calibration from views of a printed checkerboard.

`pattern` parses the board's SPEC, `camera_model` holds OpenCV's rational lens model,
`detect` finds and refines the board's corners (with their uncertainty), `solve` is the
joint bundle adjustment of intrinsics, rig, board poses and board flatness, `views`
reads a views directory, `result` writes calibration.json and camN.yml, `pictures`
draws the residual, coverage and uncertainty maps; `field` refines a quad's calibration
for drift from ordinary scenes (`mismatch` measures each tile's pair offsets).
"""
