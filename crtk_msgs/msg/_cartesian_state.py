# generated from rosidl_generator_py/resource/_idl.py.em
# with input from crtk_msgs:msg/CartesianState.idl
# generated code does not contain a copyright notice

# This is being done at the module level and not on the instance level to avoid looking
# for the same variable multiple times on each instance. This variable is not supposed to
# change during runtime so it makes sense to only look for it once.
from os import getenv

ros_python_check_fields = getenv('ROS_PYTHON_CHECK_FIELDS', default='')


# Import statements for member types

import builtins  # noqa: E402, I100

import rosidl_parser.definition  # noqa: E402, I100


class Metaclass_CartesianState(type):
    """Metaclass of message 'CartesianState'."""

    _CREATE_ROS_MESSAGE = None
    _CONVERT_FROM_PY = None
    _CONVERT_TO_PY = None
    _DESTROY_ROS_MESSAGE = None
    _TYPE_SUPPORT = None

    __constants = {
    }

    @classmethod
    def __import_type_support__(cls):
        try:
            from rosidl_generator_py import import_type_support
            module = import_type_support('crtk_msgs')
        except ImportError:
            import logging
            import traceback
            logger = logging.getLogger(
                'crtk_msgs.msg.CartesianState')
            logger.debug(
                'Failed to import needed modules for type support:\n' +
                traceback.format_exc())
        else:
            cls._CREATE_ROS_MESSAGE = module.create_ros_message_msg__msg__cartesian_state
            cls._CONVERT_FROM_PY = module.convert_from_py_msg__msg__cartesian_state
            cls._CONVERT_TO_PY = module.convert_to_py_msg__msg__cartesian_state
            cls._TYPE_SUPPORT = module.type_support_msg__msg__cartesian_state
            cls._DESTROY_ROS_MESSAGE = module.destroy_ros_message_msg__msg__cartesian_state

            from geometry_msgs.msg import Pose
            if Pose.__class__._TYPE_SUPPORT is None:
                Pose.__class__.__import_type_support__()

            from geometry_msgs.msg import Twist
            if Twist.__class__._TYPE_SUPPORT is None:
                Twist.__class__.__import_type_support__()

            from geometry_msgs.msg import Wrench
            if Wrench.__class__._TYPE_SUPPORT is None:
                Wrench.__class__.__import_type_support__()

            from std_msgs.msg import Bool
            if Bool.__class__._TYPE_SUPPORT is None:
                Bool.__class__.__import_type_support__()

            from std_msgs.msg import Header
            if Header.__class__._TYPE_SUPPORT is None:
                Header.__class__.__import_type_support__()

    @classmethod
    def __prepare__(cls, name, bases, **kwargs):
        # list constant names here so that they appear in the help text of
        # the message class under "Data and other attributes defined here:"
        # as well as populate each message instance
        return {
        }


class CartesianState(metaclass=Metaclass_CartesianState):
    """Message class 'CartesianState'."""

    __slots__ = [
        '_header',
        '_pose',
        '_pose_is_valid',
        '_twist',
        '_twist_is_valid',
        '_wrench',
        '_wrench_is_valid',
        '_check_fields',
    ]

    _fields_and_field_types = {
        'header': 'std_msgs/Header',
        'pose': 'geometry_msgs/Pose',
        'pose_is_valid': 'std_msgs/Bool',
        'twist': 'geometry_msgs/Twist',
        'twist_is_valid': 'std_msgs/Bool',
        'wrench': 'geometry_msgs/Wrench',
        'wrench_is_valid': 'std_msgs/Bool',
    }

    # This attribute is used to store an rosidl_parser.definition variable
    # related to the data type of each of the components the message.
    SLOT_TYPES = (
        rosidl_parser.definition.NamespacedType(['std_msgs', 'msg'], 'Header'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['geometry_msgs', 'msg'], 'Pose'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['std_msgs', 'msg'], 'Bool'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['geometry_msgs', 'msg'], 'Twist'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['std_msgs', 'msg'], 'Bool'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['geometry_msgs', 'msg'], 'Wrench'),  # noqa: E501
        rosidl_parser.definition.NamespacedType(['std_msgs', 'msg'], 'Bool'),  # noqa: E501
    )

    def __init__(self, **kwargs):
        if 'check_fields' in kwargs:
            self._check_fields = kwargs['check_fields']
        else:
            self._check_fields = ros_python_check_fields == '1'
        if self._check_fields:
            assert all('_' + key in self.__slots__ for key in kwargs.keys()), \
                'Invalid arguments passed to constructor: %s' % \
                ', '.join(sorted(k for k in kwargs.keys() if '_' + k not in self.__slots__))
        from std_msgs.msg import Header
        self.header = kwargs.get('header', Header())
        from geometry_msgs.msg import Pose
        self.pose = kwargs.get('pose', Pose())
        from std_msgs.msg import Bool
        self.pose_is_valid = kwargs.get('pose_is_valid', Bool())
        from geometry_msgs.msg import Twist
        self.twist = kwargs.get('twist', Twist())
        from std_msgs.msg import Bool
        self.twist_is_valid = kwargs.get('twist_is_valid', Bool())
        from geometry_msgs.msg import Wrench
        self.wrench = kwargs.get('wrench', Wrench())
        from std_msgs.msg import Bool
        self.wrench_is_valid = kwargs.get('wrench_is_valid', Bool())

    def __repr__(self):
        typename = self.__class__.__module__.split('.')
        typename.pop()
        typename.append(self.__class__.__name__)
        args = []
        for s, t in zip(self.get_fields_and_field_types().keys(), self.SLOT_TYPES):
            field = getattr(self, s)
            fieldstr = repr(field)
            # We use Python array type for fields that can be directly stored
            # in them, and "normal" sequences for everything else.  If it is
            # a type that we store in an array, strip off the 'array' portion.
            if (
                isinstance(t, rosidl_parser.definition.AbstractSequence) and
                isinstance(t.value_type, rosidl_parser.definition.BasicType) and
                t.value_type.typename in ['float', 'double', 'int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64']
            ):
                if len(field) == 0:
                    fieldstr = '[]'
                else:
                    if self._check_fields:
                        assert fieldstr.startswith('array(')
                    prefix = "array('X', "
                    suffix = ')'
                    fieldstr = fieldstr[len(prefix):-len(suffix)]
            args.append(s + '=' + fieldstr)
        return '%s(%s)' % ('.'.join(typename), ', '.join(args))

    def __eq__(self, other):
        if not isinstance(other, self.__class__):
            return False
        if self.header != other.header:
            return False
        if self.pose != other.pose:
            return False
        if self.pose_is_valid != other.pose_is_valid:
            return False
        if self.twist != other.twist:
            return False
        if self.twist_is_valid != other.twist_is_valid:
            return False
        if self.wrench != other.wrench:
            return False
        if self.wrench_is_valid != other.wrench_is_valid:
            return False
        return True

    @classmethod
    def get_fields_and_field_types(cls):
        from copy import copy
        return copy(cls._fields_and_field_types)

    @builtins.property
    def header(self):
        """Message field 'header'."""
        return self._header

    @header.setter
    def header(self, value):
        if self._check_fields:
            from std_msgs.msg import Header
            assert \
                isinstance(value, Header), \
                "The 'header' field must be a sub message of type 'Header'"
        self._header = value

    @builtins.property
    def pose(self):
        """Message field 'pose'."""
        return self._pose

    @pose.setter
    def pose(self, value):
        if self._check_fields:
            from geometry_msgs.msg import Pose
            assert \
                isinstance(value, Pose), \
                "The 'pose' field must be a sub message of type 'Pose'"
        self._pose = value

    @builtins.property
    def pose_is_valid(self):
        """Message field 'pose_is_valid'."""
        return self._pose_is_valid

    @pose_is_valid.setter
    def pose_is_valid(self, value):
        if self._check_fields:
            from std_msgs.msg import Bool
            assert \
                isinstance(value, Bool), \
                "The 'pose_is_valid' field must be a sub message of type 'Bool'"
        self._pose_is_valid = value

    @builtins.property
    def twist(self):
        """Message field 'twist'."""
        return self._twist

    @twist.setter
    def twist(self, value):
        if self._check_fields:
            from geometry_msgs.msg import Twist
            assert \
                isinstance(value, Twist), \
                "The 'twist' field must be a sub message of type 'Twist'"
        self._twist = value

    @builtins.property
    def twist_is_valid(self):
        """Message field 'twist_is_valid'."""
        return self._twist_is_valid

    @twist_is_valid.setter
    def twist_is_valid(self, value):
        if self._check_fields:
            from std_msgs.msg import Bool
            assert \
                isinstance(value, Bool), \
                "The 'twist_is_valid' field must be a sub message of type 'Bool'"
        self._twist_is_valid = value

    @builtins.property
    def wrench(self):
        """Message field 'wrench'."""
        return self._wrench

    @wrench.setter
    def wrench(self, value):
        if self._check_fields:
            from geometry_msgs.msg import Wrench
            assert \
                isinstance(value, Wrench), \
                "The 'wrench' field must be a sub message of type 'Wrench'"
        self._wrench = value

    @builtins.property
    def wrench_is_valid(self):
        """Message field 'wrench_is_valid'."""
        return self._wrench_is_valid

    @wrench_is_valid.setter
    def wrench_is_valid(self, value):
        if self._check_fields:
            from std_msgs.msg import Bool
            assert \
                isinstance(value, Bool), \
                "The 'wrench_is_valid' field must be a sub message of type 'Bool'"
        self._wrench_is_valid = value
