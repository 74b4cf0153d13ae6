"""letspi.llm"""
