"""Every estimator judged side by side, in four rooms: :mod:`.running` (each method run through the plugin
isolation: :func:`run_methods`), :mod:`.verification` (the result entries, the narrower-than-hull proof:
:func:`judge`, :class:`HullReference`), :mod:`.aggregation` (campaign statistics, Clopper-Pearson) and
:mod:`.output` (tables, plots). Their names are importable from here as before.
"""

from h4bench.scenarios.judging.aggregation import clopper_pearson, summarise_methods
from h4bench.scenarios.judging.output import judged_table, plot_coverage
from h4bench.scenarios.judging.running import Outcome, describe_estimators, parse_methods, run_method, run_methods
from h4bench.scenarios.judging.verification import HULL_RTOL, HullReference, hull_reference, judge

__all__ = ["HULL_RTOL", "HullReference", "Outcome", "clopper_pearson", "describe_estimators", "hull_reference",
           "judge", "judged_table", "parse_methods", "plot_coverage", "run_method", "run_methods",
           "summarise_methods"]
