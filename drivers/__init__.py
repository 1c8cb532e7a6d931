"""Device drivers: one module or package per device kind, each real driver with its fake beside it."""
