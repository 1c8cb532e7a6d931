from crtk_msgs.msg._operating_state import OperatingState  # noqa: F401
from crtk_msgs.msg._string_stamped import StringStamped  # noqa: F401
