"""The motors' safety budget: settings that cannot stop the wheels within 100 ms of a fault are refused.

Two stops bound the time from a fault to "all wheels commanded to 0":
* a controller that stops answering is detected after (1 + retries) × command_timeout_s (each attempt
  with its short grace listen, `bus.GRACE_FRACTION`), counted from the next request — up to one
  control period after the fault — and the driver then writes the stops;
* a pulled cable (or a hung host) leaves only each controller's own serial timeout (command 14),
  which stops it failsafe_timeout_s after the last byte it received.
"""

from __future__ import annotations

from gprbot.config import CONTROL_PERIOD_S, MotorsConfig
from gprbot.drivers.motors.bus import GRACE_FRACTION
from gprbot.drivers.motors.protocol import FIRST_ADDRESS, LAST_ADDRESS
from gprbot.errors import ConfigError

FAULT_STOP_BOUND_S = 0.1  # requirement: wheels commanded to stop within 100 ms of any fault
# CONTROL_PERIOD_S (config): the motion loop's period, so a fault can sit that long before a request


def check_motors_config(cfg: MotorsConfig) -> None:
    """Raise ConfigError if the motors section is inconsistent or cannot stop within 100 ms of a fault."""
    if not cfg.wheel_map or len(set(cfg.wheel_map)) != len(cfg.wheel_map):
        raise ConfigError(f"motors.wheel_map: expected distinct (address, channel) pairs, got {cfg.wheel_map}")
    for address, channel in cfg.wheel_map:
        if not FIRST_ADDRESS <= address <= LAST_ADDRESS or channel not in (1, 2):
            raise ConfigError(
                f"motors.wheel_map: ({address}, {channel}) is not (address 128..135, channel 1|2)"
            )
    for key in ("encoder_counts_per_rev", "max_wheel_speed_rad_s", "max_wheel_accel_rad_s2", "command_timeout_s"):
        if not getattr(cfg, key) > 0:
            raise ConfigError(f"motors.{key}: must be > 0, got {getattr(cfg, key)}")
    if cfg.retries < 0:
        raise ConfigError(f"motors.retries: must be >= 0, got {cfg.retries}")
    if not 0.1 <= round(cfg.failsafe_timeout_s, 1) <= FAULT_STOP_BOUND_S:
        raise ConfigError(
            f"motors.failsafe_timeout_s: {cfg.failsafe_timeout_s} s; it is the only stop when the cable "
            f"is pulled, so it must be 0.1 s (the controller counts in 100 ms steps and 0 disables it)"
        )
    detection = (1 + cfg.retries) * cfg.command_timeout_s * (1 + GRACE_FRACTION)
    if detection + CONTROL_PERIOD_S > FAULT_STOP_BOUND_S + 1e-9:
        raise ConfigError(
            f"motors.command_timeout_s × (1 + motors.retries) × {1 + GRACE_FRACTION:g} (each attempt's grace) = "
            f"{detection:.3f} s: a silent controller is detected too late to stop within {FAULT_STOP_BOUND_S} s; "
            f"keep it <= {FAULT_STOP_BOUND_S - CONTROL_PERIOD_S:.2f} s (e.g. 0.02 s and 2 retries)"
        )
