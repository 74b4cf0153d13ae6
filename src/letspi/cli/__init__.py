"""letspi.cli"""
