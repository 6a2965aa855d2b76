"""ilcc_graph: LiDAR-camera extrinsic calibration with a printed chessboard and a GTSAM factor graph.

The pipeline stages and the estimation core; the command line is ``ilcc_graph.app`` (``ilcc-graph``).
"""
