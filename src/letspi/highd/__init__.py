"""letspi.highd"""
