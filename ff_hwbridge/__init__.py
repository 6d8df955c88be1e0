"""ff_hwbridge: CiA 402 / Maxon EPOS CANopen driver, bridge node and simulated drive."""
