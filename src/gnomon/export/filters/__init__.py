"""One module per exported filter family: its ``SPECS`` (``gnomon.export.FilterSpec``),
the files of its C twin and the order of its C parameter struct. ``gnomon.export.SPECS``
collects them all."""
