from crtk_msgs.msg._cartesian_impedance import CartesianImpedance  # noqa: F401
from crtk_msgs.msg._cartesian_impedance_half_plane_gains import CartesianImpedanceHalfPlaneGains  # noqa: F401
from crtk_msgs.msg._cartesian_servo import CartesianServo  # noqa: F401
from crtk_msgs.msg._cartesian_state import CartesianState  # noqa: F401
from crtk_msgs.msg._joint_servo import JointServo  # noqa: F401
from crtk_msgs.msg._operating_state import OperatingState  # noqa: F401
from crtk_msgs.msg._setpoint_mode import SetpointMode  # noqa: F401
from crtk_msgs.msg._string_stamped import StringStamped  # noqa: F401
