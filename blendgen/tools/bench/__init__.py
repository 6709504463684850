"""The `dockbench bench` commands: cost and fidelity of each stage against its reference."""
