"""How long runs execute, independent of what they compute.

``ordered``: one task per scenario, N at a time, results written in scenario order by one writer
(the LLM phases and the evaluation harness use it). ``interrupt``: how every long command stops on
Ctrl-C (one line, exit 130, no process left running).
"""
