"""letspi.evaluation"""
