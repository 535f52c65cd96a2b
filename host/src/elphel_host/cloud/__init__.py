"""Point clouds: the PLY format (`ply`), cloud-to-cloud distances (`compare`), pictures."""
