"""cablebot controller: kinematics, control loop, daemon, Zenoh interface and CLI."""
