"""The built-in pipeline stages, one file each, registered in run order (``equipose.runtime.stage``).

copies → rescore → consensus → view → calibrate → select → polish → rest_facet → upright → frame_priors → flip →
turn → flip_risk → cylinder → rest_side → stand_upright → rim_axis → axis_centre → handle → seat; instance mode: instance; both modes
then run confidence; category mode ends with centre.
"""
from equipose.runtime.stages import copies, rescore, consensus, view, calibrate, select, polish  # noqa: F401
from equipose.runtime.stages import rest_facet, upright, frame_priors, flip, turn, flip_risk  # noqa: F401
from equipose.runtime.stages import cylinder, rest_side  # noqa: F401
from equipose.runtime.stages import stand_upright, rim_axis, axis_centre, handle, seat  # noqa: F401
from equipose.runtime.stages import instance, confidence, centre  # noqa: F401
