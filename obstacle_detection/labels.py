"""The label values shared by the layers: the one home of every pixel and cell constant.

Three families, each a small integer code:

- ``LABEL_*``: what the pipeline decided for each pixel of a depth image
  (``DetectionResult.labels``, uint8).
- ``GT_*``: the ground truth of a pixel, written by the scene generator
  (:mod:`obstacle_detection.sim.render`) and by labelled folders, read by the evaluation.
- ``CELL_*``: the value of a costmap cell (nav_msgs/OccupancyGrid convention, int8).

This module imports nothing, so every layer (numba kernels included: numba reads module-level
integers as compile-time constants) may take its values from here.
"""

# --------------------------------------------------------------------------- pipeline labels

LABEL_NO_RETURN = 0    #: no depth (0, NaN, out of sensor range, cropped)
LABEL_OUTSIDE_ROI = 1  #: a 3-D point outside the region of interest
LABEL_GROUND = 2       #: in a voxel that passed the slope test (traversable)
LABEL_OBSTACLE = 3     #: in a voxel that is a validated obstacle

# --------------------------------------------------------------------------- ground truth

GT_NO_RETURN = 0       #: no surface hit (out of band, dropout, border)
GT_TRAVERSABLE = 1     #: traversable ground
GT_OBSTACLE = 2        #: an obstacle
#: Robot-level truth only: a surface higher than the robot above the ground under it; not an
#: obstacle, a free point in the costmap's cells.
GT_ABOVE_ROBOT = 3

# --------------------------------------------------------------------------- costmap cells

CELL_UNKNOWN = -1      #: nothing was seen in the cell
CELL_FREE = 0          #: only traversable ground was seen in the cell
CELL_OCCUPIED = 100    #: an obstacle point fell in the cell
