"""letspi.metrics"""
