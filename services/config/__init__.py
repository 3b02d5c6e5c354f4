"""The robot description: one TOML file, a shared ``[robot]`` table and one table per service.

Its rooms: :mod:`~services.config.fields` (bounds, units, the base section, ``"none"``),
:mod:`~services.config.sections`, :mod:`~services.config.sensors` and :mod:`~services.config.run_sections`
(the section types, every default), :mod:`~services.config.description` (the whole description), :mod:`~services.config.loading`
(the file and ``--set``, strictly), :mod:`~services.config.writing` (back to TOML) and
:mod:`~services.config.reference` (the parameter reference of docs/configuration.md). The names
below are what the rest of the project imports, from ``services.config``.
"""

from services.config.description import SECTIONS, SEED_NAMES, Config
from services.config.fields import NONE, NonNegative, Positive, optional_fields, require_finite_fields
from services.config.loading import (
    apply_overrides,
    config_from_description,
    convert_toml,
    load_config,
    parse_override,
    read_description,
)
from services.config.navigation import NavigationConfig
from services.config.run_sections import (
    NAMESPACE,
    CpuChoice,
    GcPolicy,
    RecordConfig,
    RecordRate,
    Ros2Config,
    RtConfig,
    TfLayout,
)
from services.config.sections import (
    CalibratedGeometry,
    DriveConfig,
    GoalsConfig,
    InputConfig,
    LocalizationConfig,
    MotorConfig,
    OdometryConfig,
    RobotConfig,
    SimConfig,
    SimEngine,
    SimMode,
    TargetAngleMode,
)
from services.config.sensors import CollisionMonitorConfig, ImuConfig, LidarConfig
from services.config.sim_body import SIM_BODY_KEYS, SIM_SET_FLAG, parse_sim_set
from services.config.writing import description_toml
from services.errors import ConfigError

__all__ = [
    "NAMESPACE",
    "NONE",
    "SECTIONS",
    "SEED_NAMES",
    "SIM_BODY_KEYS",
    "SIM_SET_FLAG",
    "CalibratedGeometry",
    "CollisionMonitorConfig",
    "Config",
    "ConfigError",
    "CpuChoice",
    "DriveConfig",
    "GcPolicy",
    "GoalsConfig",
    "ImuConfig",
    "InputConfig",
    "LidarConfig",
    "LocalizationConfig",
    "MotorConfig",
    "NavigationConfig",
    "NonNegative",
    "OdometryConfig",
    "Positive",
    "RecordConfig",
    "RecordRate",
    "RobotConfig",
    "Ros2Config",
    "RtConfig",
    "SimConfig",
    "SimEngine",
    "SimMode",
    "TargetAngleMode",
    "TfLayout",
    "apply_overrides",
    "config_from_description",
    "convert_toml",
    "description_toml",
    "load_config",
    "optional_fields",
    "parse_override",
    "parse_sim_set",
    "read_description",
    "require_finite_fields",
]
