"""Maps and instances that more than one part needs: map generators, named maps, placement, benchmark data."""
