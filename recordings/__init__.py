"""What users record, read: bags, Kinect and phone recordings, folders and datasets, with their cameras.

Every format's reader, its lenses and the registration of depth to colour, apart from the trainer and
free of torch, so that ``fit`` and ``rgb2cloud stream`` read a recording the same way and the serving
install can stream one (``pip install .[recordings]``). ``formats`` is the one place formats are told
apart and opened.
"""
