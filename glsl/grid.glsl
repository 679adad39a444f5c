// The guides' sector grid a x b, from the `params` push constants.
#ifndef QTRACE_GRID_GLSL
#define QTRACE_GRID_GLSL

uint grid_a() {
    return params.sector_grid & 0xffffu;
}

uint grid_b() {
    return params.sector_grid >> 16;
}

uint sector_count() {
    return grid_a() * grid_b();
}

// Units in one column of a volume's alias table, floor(65535 / n) (see
// SectorEntry); the float division is exact after the floor, as its
// fraction is at least 1 / n, far above its rounding.
uint sector_column_units() {
    return uint(65535.0 / float(sector_count()));
}

#endif
