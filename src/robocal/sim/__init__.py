"""The digital twin: campaigns in the data contract with a truth file (:mod:`robocal.sim.twin`), its effects
(thermal, compliance, drift), the comparison of a calibration with the truth, and the closed-loop experiments
run on the twin's cell against the compensation service (:mod:`robocal.sim.closed_loop`,
:mod:`robocal.sim.closed_loop_effects`). Importing it reads and writes nothing."""
