"""letspi.sumo"""
