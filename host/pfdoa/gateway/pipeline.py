"""The gateway pipeline, by concern (this module only re-exports them):

* :mod:`pfdoa.gateway.decoding` - :class:`Gateway`: chunks -> decoded messages -> readings
  with their anchors' event times -> the reassembler (:func:`pfdoa.readings.grouping.make_grouper`);
* :mod:`pfdoa.gateway.localizer` - :class:`Localizer`: anchor sets -> estimator (with the
  odometry over each set's interval) -> output records;
* :mod:`pfdoa.gateway.odomsource` - live odometry (:class:`OdometryReader`) and odometry
  files (:func:`load_odometry`) for the :class:`~pfdoa.odometry.OdometryBuffer`;
* :mod:`pfdoa.gateway.runner` - :class:`Runner`: reader threads, the one queue, timers,
  capture, health, stopping;
* :func:`pfdoa.gateway.setup.build_pipeline` - the one builder of the data path (both
  commands, the fleet simulator and its benchmark).
"""

from pfdoa.gateway.decoding import MAX_DECODERS, Gateway
from pfdoa.gateway.localizer import Localizer
from pfdoa.gateway.odomsource import OdometryReader, load_odometry
from pfdoa.gateway.runner import Runner
from pfdoa.odometry import ODOM_MAX as ODOM_QUEUE
from pfdoa.readings.grouping import make_grouper

__all__ = ["MAX_DECODERS", "ODOM_QUEUE", "Gateway", "Localizer", "OdometryReader", "Runner", "load_odometry",
           "make_grouper"]
