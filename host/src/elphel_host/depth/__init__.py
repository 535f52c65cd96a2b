"""Depth from disparity: depth maps in millimetres and point clouds of a quad's DSI."""
