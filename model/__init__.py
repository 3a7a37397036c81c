"""rgb2cloud trainer package.

The torch-free modules (``geometry``, ``codec``, ``config``, ``card``) are
shared with the service; everything else imports torch.
"""
