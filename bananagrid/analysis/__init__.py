"""Analysis of computed maps: radial laws along rays, comparisons (Tables 1 and 2 of the
polar-banana paper), the Figure 7 sweep, contours, and the bearing-fix validation table."""
