"""Robot models: the H4 regressor and its parameters (:mod:`ident.robots.h4`), URDF serial robots
(:mod:`ident.robots.serial`, pinocchio loaded on use) and the TX40 log (:mod:`ident.robots.tx40`)."""
