"""letspi.bench"""
