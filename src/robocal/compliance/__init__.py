"""Heavy-load compliance (Mao et al. 2021): joint compliance from motor currents / torques / gravity, the POE
decoupling into controller parameters, compensation and the load table. Importing reads and writes nothing."""

from robocal.compliance.model import ComplianceModel

__all__ = ["ComplianceModel"]
