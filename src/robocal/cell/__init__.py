"""Into the cell: robot descriptions from and to URDF (:mod:`robocal.cell.urdf`) and vendor robot programs
compensated with a calibration bundle (:mod:`robocal.cell.programs`)."""
