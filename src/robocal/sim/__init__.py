"""The digital twin: campaigns in the data contract with a truth file (:mod:`robocal.sim.twin`), its effects
(thermal, compliance, drift) and the comparison of a calibration with the truth. Importing it reads and writes
nothing."""
