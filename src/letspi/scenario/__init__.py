"""letspi.scenario"""
