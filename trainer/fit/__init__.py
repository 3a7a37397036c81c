"""``rgb2cloud fit``: a short RGB-D recording of one place in, a verified, published model of it out.

recording (open any supported layout as pairs in time order) -> inspection (units,
holes, registration) -> split (train | gap | held-out tail) -> budget (steps that fit
the minutes) -> workflow (train, score beside the starting model and the baselines,
export, publish).
"""
