"""The controller service: config, control step, fixed-rate runner, offsets store, Zenoh, daemon."""
