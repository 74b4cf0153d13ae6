"""How long runs execute, independent of what they compute: ``ordered`` (N tasks in flight, one writer
in scenario order) and ``interrupt`` (how every long command stops on Ctrl-C)."""
