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

// Units in one column of an alias table of n entries, floor(65535 / n) (see
// SectorEntry); the float division is exact after the floor, as its
// fraction is at least 1 / n, far above its rounding.
uint column_units(uint n) {
    return uint(65535.0 / float(n));
}

uint sector_column_units() {
    return column_units(sector_count());
}

// How many lights the guides pick NEE's among (LightGroup), where they do.
uint light_groups() {
    return params.flags >> LIGHT_GROUPS_SHIFT;
}

// Where volume v's alias table over the scene's lights starts in the
// sector tables' buffer: after every volume's sectors. Row volume_count
// (NO_VOLUME's) follows emitted power alone.
uint light_row(uint v) {
    uint row = v == NO_VOLUME ? params.volume_count : v;
    return params.volume_count * sector_count() + row * light_groups();
}

#endif
