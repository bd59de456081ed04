"""Data processing: filters, derivatives, decimation (:mod:`ident.processing.filtering`) and the paper's chain that
builds the equation ``y = W theta + e`` (:mod:`ident.processing.processing`)."""
