"""ff_executor: timed setpoint streaming of current profiles, and its action-server node."""
