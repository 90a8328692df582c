"""The pixel and cell codes every layer shares (it imports nothing; numba reads them too).

``LABEL_*``: the pipeline's decision per pixel (uint8); ``GT_*``: a pixel's ground truth;
``CELL_*``: a costmap cell (nav_msgs/OccupancyGrid, int8).
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
