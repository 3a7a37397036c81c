"""Dataset readers (one per on-disk format) and paired training transforms."""
