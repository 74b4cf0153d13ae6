"""letspi.planners"""
