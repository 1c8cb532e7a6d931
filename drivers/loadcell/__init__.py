"""The Arduino load cell: wire protocol, host drivers (serial, CAN), calibration, firmware fake, simulated twin."""
