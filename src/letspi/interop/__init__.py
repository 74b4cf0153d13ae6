"""letspi.interop: exchange with other tools' formats (optional extras; imported only where used).

``commonroad``: scenarios and plans as CommonRoad files (extra ``commonroad``).
"""
