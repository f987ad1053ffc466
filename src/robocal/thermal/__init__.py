"""Temperature-dependent kinematics: thermal model, sensitivity screening, compensation and validation."""
