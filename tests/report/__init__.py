"""Tests of robocal.report."""
