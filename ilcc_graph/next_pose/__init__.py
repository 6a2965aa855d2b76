"""Where to hold the board next: the pose that shrinks the worst-determined part of the extrinsic most.

The extrinsic's information now is the inverse of its marginal covariance (batch or iSAM2). A new
board at pose ``T_lidar_board`` adds, through the graph's own two factors on (``X(0)``, ``B(new)``),

    dI = A_x^T A_x - A_x^T A_b (A_b^T A_b + Sigma_B^-1)^-1 A_b^T A_x,

where ``A_x, A_b`` are the whitened Jacobians of that board's grouped bearing factor
(``graphs.frame_bearing_factor``: the corners projected with the current extrinsic, each with the
median pixel covariance of the image corners seen so far) and ``Sigma_B`` the LiDAR board prior's
covariance predicted for that pose (:class:`BoardNoiseModel`): the LiDAR's beam table is cast on
the board to get its returns; the plane block (rx, ry, tz) is ``a (A^T A)^-1 + b`` x the same
sandwich with one range bias per beam (what the stage's ring jackknife sees); the in-plane block
(rz, tx, ty) ``c`` x the inverse information of the stage's soft-edged intensity model at those
returns plus ``d`` x the stage's own edge-sampling covariance (``lidar.covariance``), with the
stage's ray coupling between them. ``a..d`` are fitted (non-negative least squares) to the
covariances the LiDAR stage gave for the boards so far.

Candidates: board centres around the rig (every 30 deg of azimuth for a panorama, across the
image otherwise) at 1.2-3.4 m and three heights inside the LiDAR's vertical field, the board
facing the rig, turned about the vertical and tilted up or down by up to 40 deg, held as a diamond
(45 deg in its plane, as the paper's layout). A candidate counts only when every board corner
lies in the image (3 % border) and in front of the camera, the whole board inside the LiDAR's
vertical field, at least 4 beams cross it, and it is not where a board was already (its centre
15 cm and its face 10 deg from every earlier one's). The score is the largest sigma after the frame,
each divided by the target (``target_sigma``; default 0.1 deg / 1 mm for the scale only): the
proposal is the candidate with the smallest, then refined around it. The coarse grid is searched in
two steps: every centre facing the rig, then the turns and tilts at the ``TURNED_CENTRES`` best of
those and at every centre where facing gives no candidate (on 11 simulated and recorded runs the
same proposal as the whole grid, in 1.3-2.6x less time).

The new frame's noise is the one the run found (``from_calibration``, and ``check``'s running solve):
the boards' and corners' covariances times the variance components of the sensor model it chose,
its information divided by the final variance factor or the model's held-out factor. The LiDAR's own
error terms (``beams``, ``range``) are not part of the prediction: a new board is predicted as a
6-dof LiDAR pose with the component of the in-plane priors.
"""

from ilcc_graph.next_pose.advisor import (
    TURNED_CENTRES,
    TURNS,
    Advisor,
    Proposal,
    candidate_azimuths,
    for_run,
    frame_information,
    from_calibration,
    held_out_factor,
    median_pixel_cov,
    noise_scaled,
    propose,
)
from ilcc_graph.next_pose.lidar_noise import BoardNoiseModel, fit_noise_model
from ilcc_graph.next_pose.pose_geometry import Rig, beam_hits, board_outline, board_pose, in_view

__all__ = [
    "Advisor",
    "BoardNoiseModel",
    "Proposal",
    "TURNED_CENTRES",
    "TURNS",
    "Rig",
    "beam_hits",
    "board_outline",
    "board_pose",
    "candidate_azimuths",
    "fit_noise_model",
    "for_run",
    "frame_information",
    "from_calibration",
    "in_view",
    "held_out_factor",
    "median_pixel_cov",
    "noise_scaled",
    "propose",
]
