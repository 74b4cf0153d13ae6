"""letspi.physics"""
