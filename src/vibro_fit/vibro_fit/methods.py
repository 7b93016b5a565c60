"""The identification methods, in a module of its own so that command-line parsers list them without
loading the identification (scipy.optimize) at start-up."""

#: ``paper``: each flight's parabola fitted alone (Eq. 3, 14), impacts where consecutive parabolas meet
#: (Eq. 15); ``joint``: the two flights around each impact refitted together, constrained to meet on the
#: plate (:func:`vibro_fit.impacts.joint_impact`).
METHODS = ("paper", "joint")
