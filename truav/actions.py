"""The UAV action numbering, one fact shared by the world model and the wire protocol.

An action is an int in [0, N_ACTIONS): actions 0-7 fly at half the maximum speed and 8-15 at full
speed, heading 45 degrees x (action % 8), counterclockwise from east (+x). HOVER (-1) is an explicit
hover (a missing action, or the central scheme's autopilot without commands). Kept in the base layer,
free of numpy and numba, so that bus processes which only check actions load neither.
"""

N_ACTIONS = 16
HOVER = -1
