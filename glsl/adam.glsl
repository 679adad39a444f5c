// Adam's update of one network parameter; for the two Adam passes.
#ifndef QTRACE_ADAM_GLSL
#define QTRACE_ADAM_GLSL

layout(push_constant) uniform Push { MlpPush push; };
// Adam's first and second moment per parameter.
layout(std430, set = 0, binding = B_MLP_MOMENTS) buffer Moments { vec2 moments[]; };
layout(std430, set = 0, binding = B_MLP_GRAD) writeonly buffer Grad { float grad[]; };

// One step on parameter p with gradient g (the batch mean).
void adam_step(uint p, float g) {
    grad[p] = g;
    vec2 m = moments[p];
    m.x = push.beta1 * m.x + (1.0 - push.beta1) * g;
    m.y = push.beta2 * m.y + (1.0 - push.beta2) * g * g;
    moments[p] = m;
    float c1 = 1.0 - pow(push.beta1, float(push.step));
    float c2 = 1.0 - pow(push.beta2, float(push.step));
    mlp_params[p >> 2][p & 3u] -= push.learning_rate * (m.x / c1) / (sqrt(m.y / c2) + push.epsilon);
}

#endif
