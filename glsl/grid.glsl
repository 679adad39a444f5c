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

#endif
