//! The Neural-Q network on the host: its shape and parameter layout (shared
//! with `glsl/mlp.glsl`), initialisation, and a CPU reference of the forward
//! pass, the gradient of one transition's loss and the Adam step, against
//! which the GPU passes are tested.
//!
//! The network maps an encoded state to one non-negative Q per sector:
//! `hidden` ReLU layers of `width` units, then a linear layer and softplus.
//! Parameters lie in one `f32` array, layer after layer, each as a row-major
//! `fan_out × fan_in` weight matrix followed by `fan_out` biases.

/// The size of every layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MlpShape {
    pub inputs: u32,
    pub width: u32,
    /// Hidden layers, at least one.
    pub hidden: u32,
    /// One Q per hemisphere sector.
    pub outputs: u32,
}

/// One dense layer: where its weights start in the parameter array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layer {
    pub fan_in: usize,
    pub fan_out: usize,
    pub offset: usize,
}

impl Layer {
    pub fn weight(&self, out: usize, inp: usize) -> usize {
        self.offset + out * self.fan_in + inp
    }
    pub fn bias(&self, out: usize) -> usize {
        self.offset + self.fan_out * self.fan_in + out
    }
    /// Its weights and biases.
    pub fn param_count(&self) -> usize {
        self.fan_out * (self.fan_in + 1)
    }
}

/// Workgroup memory every device we target offers (lavapipe's limit).
pub const MAX_WORKGROUP_BYTES: u32 = 32768;

pub fn softplus(z: f32) -> f32 {
    // log(1 + e^z) loses nothing above 15 by returning z, and cannot overflow.
    if z > 15.0 {
        z
    } else {
        z.exp().ln_1p()
    }
}

pub fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + (-z).exp())
}

/// Adam's hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Adam {
    pub learning_rate: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub epsilon: f32,
}

impl Default for Adam {
    fn default() -> Self {
        Self {
            learning_rate: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
        }
    }
}

impl Adam {
    /// Step `t` (from 1) on `params` with gradient `grad`; `m` and `v` are the
    /// moment estimates, updated in place. Same arithmetic as `mlp_adam.comp`.
    pub fn step(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], grad: &[f32], t: u32) {
        let c1 = 1.0 - self.beta1.powi(t as i32);
        let c2 = 1.0 - self.beta2.powi(t as i32);
        for i in 0..params.len() {
            m[i] = self.beta1 * m[i] + (1.0 - self.beta1) * grad[i];
            v[i] = self.beta2 * v[i] + (1.0 - self.beta2) * grad[i] * grad[i];
            params[i] -= self.learning_rate * (m[i] / c1) / ((v[i] / c2).sqrt() + self.epsilon);
        }
    }
}

impl MlpShape {
    pub fn validate(&self) -> Result<(), String> {
        if self.inputs == 0 || self.width == 0 || self.hidden == 0 || self.outputs == 0 {
            return Err(format!("every layer needs at least one unit: {self:?}"));
        }
        // Shaders read rows as vec4s and keep each invocation's vectors in
        // workgroup memory: MLP_LANES invocations, two regions (see glsl/mlp.glsl).
        if self.inputs % 4 != 0 || self.width % 4 != 0 {
            return Err(format!("inputs and width must be multiples of 4: {self:?}"));
        }
        if self.workgroup_bytes() > MAX_WORKGROUP_BYTES {
            return Err(format!(
                "a network {} wide with {} inputs needs {} KiB of workgroup memory; at most {} KiB",
                self.width,
                self.inputs,
                self.workgroup_bytes() / 1024,
                MAX_WORKGROUP_BYTES / 1024
            ));
        }
        Ok(())
    }

    /// Workgroup memory a kernel running the network needs.
    pub fn workgroup_bytes(&self) -> u32 {
        crate::shaders::MLP_LANES * 4 * (self.inputs.max(self.width) + self.width)
    }

    /// Hidden layers first, the output layer last.
    pub fn layers(&self) -> Vec<Layer> {
        let (i, w, o) = (
            self.inputs as usize,
            self.width as usize,
            self.outputs as usize,
        );
        let mut layers = Vec::new();
        let mut offset = 0;
        for l in 0..=self.hidden as usize {
            let fan_in = if l == 0 { i } else { w };
            let fan_out = if l == self.hidden as usize { o } else { w };
            let layer = Layer {
                fan_in,
                fan_out,
                offset,
            };
            offset += layer.param_count();
            layers.push(layer);
        }
        layers
    }

    pub fn param_count(&self) -> usize {
        self.layers().iter().map(Layer::param_count).sum()
    }

    /// The values of the shader's specialization constants 0..4.
    pub fn constants(&self) -> [u32; 4] {
        [self.inputs, self.width, self.hidden, self.outputs]
    }

    /// He-uniform weights for the ReLU layers, small output weights, and
    /// output biases that make every initial Q equal to `q0`.
    pub fn init(&self, seed: u64, q0: f32) -> Vec<f32> {
        let mut state = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        let mut uniform = move || {
            // xorshift64*: reproducible without a dependency.
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            let bits = state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40;
            bits as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let layers = self.layers();
        let mut params = vec![0.0; self.param_count()];
        for (l, layer) in layers.iter().enumerate() {
            let output = l + 1 == layers.len();
            let bound = if output {
                0.1 / (layer.fan_in as f32).sqrt()
            } else {
                (6.0 / layer.fan_in as f32).sqrt()
            };
            for o in 0..layer.fan_out {
                for i in 0..layer.fan_in {
                    params[layer.weight(o, i)] = bound * uniform();
                }
                // softplus(b) = q0.
                params[layer.bias(o)] = if output { q0.exp_m1().ln() } else { 0.0 };
            }
        }
        params
    }

    /// Every layer's activations for input `x`: the hidden layers' ReLU
    /// outputs, then the output layer's pre-activations z (Q = softplus(z)).
    fn activations(&self, params: &[f32], x: &[f32]) -> Vec<Vec<f32>> {
        let mut acts: Vec<Vec<f32>> = Vec::new();
        let layers = self.layers();
        for (l, layer) in layers.iter().enumerate() {
            let input = if l == 0 { x } else { &acts[l - 1] };
            let out: Vec<f32> = (0..layer.fan_out)
                .map(|o| {
                    let z = (0..layer.fan_in).fold(params[layer.bias(o)], |z, i| {
                        z + params[layer.weight(o, i)] * input[i]
                    });
                    if l + 1 == layers.len() {
                        z
                    } else {
                        z.max(0.0)
                    }
                })
                .collect();
            acts.push(out);
        }
        acts
    }

    /// Q for every sector at input `x`.
    pub fn forward(&self, params: &[f32], x: &[f32]) -> Vec<f32> {
        let acts = self.activations(params, x);
        acts.last().unwrap().iter().map(|&z| softplus(z)).collect()
    }

    /// Adds to `grad` the gradient of the relative loss
    /// ½(target − Q(x)_k)² / (Q(x)_k² + ε), the denominator held constant
    /// (ε = 1 / MLP_LOSS_EPSILON_INV), and returns that loss.
    pub fn gradient(
        &self,
        params: &[f32],
        x: &[f32],
        k: usize,
        target: f32,
        grad: &mut [f32],
    ) -> f32 {
        let acts = self.activations(params, x);
        let layers = self.layers();
        let z = acts.last().unwrap()[k];
        let q = softplus(z);
        let out = *layers.last().unwrap();
        // dLoss/dz_k; the other outputs do not enter the loss.
        let relative = relative_weight(q);
        let delta_out = (q - target) * sigmoid(z) * relative;
        let last_hidden = &acts[layers.len() - 2];
        for i in 0..out.fan_in {
            grad[out.weight(k, i)] += delta_out * last_hidden[i];
        }
        grad[out.bias(k)] += delta_out;
        // Deltas of the last hidden layer, then back through the others.
        let mut delta: Vec<f32> = (0..out.fan_in)
            .map(|i| {
                if last_hidden[i] > 0.0 {
                    params[out.weight(k, i)] * delta_out
                } else {
                    0.0
                }
            })
            .collect();
        for l in (0..layers.len() - 1).rev() {
            let layer = layers[l];
            let input = if l == 0 { x } else { &acts[l - 1] };
            for o in 0..layer.fan_out {
                for i in 0..layer.fan_in {
                    grad[layer.weight(o, i)] += delta[o] * input[i];
                }
                grad[layer.bias(o)] += delta[o];
            }
            if l > 0 {
                delta = (0..layer.fan_in)
                    .map(|i| {
                        if input[i] > 0.0 {
                            (0..layer.fan_out)
                                .map(|o| params[layer.weight(o, i)] * delta[o])
                                .sum()
                        } else {
                            0.0
                        }
                    })
                    .collect();
            }
        }
        0.5 * (target - q) * (target - q) * relative
    }
}

/// The relative loss's weight at Q = q: 1 / (q² + ε).
pub fn relative_weight(q: f32) -> f32 {
    1.0 / (q * q + 1.0 / crate::shaders::MLP_LOSS_EPSILON_INV as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHAPE: MlpShape = MlpShape {
        inputs: 5,
        width: 7,
        hidden: 2,
        outputs: 6,
    };

    #[test]
    fn layout_is_contiguous_and_counted() {
        let layers = SHAPE.layers();
        assert_eq!(layers.len(), 3);
        assert_eq!(layers[1].offset, 7 * 5 + 7);
        assert_eq!(layers[2].offset, layers[1].offset + 7 * 7 + 7);
        assert_eq!(SHAPE.param_count(), 42 + 56 + 6 * 8);
    }

    #[test]
    fn initial_q_is_the_constant_asked_for() {
        let params = SHAPE.init(3, 0.05);
        let mut zero_out = params.clone();
        let out = *SHAPE.layers().last().unwrap();
        for o in 0..out.fan_out {
            for i in 0..out.fan_in {
                zero_out[out.weight(o, i)] = 0.0;
            }
        }
        for q in SHAPE.forward(&zero_out, &[0.3, -0.2, 0.9, 0.1, 0.5]) {
            assert!((q - 0.05).abs() < 1e-6, "{q}");
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let params = SHAPE.init(11, 0.5);
        // A few transitions, so that most units are active for one of them.
        let batch: [([f32; 5], usize, f32); 4] = [
            ([0.3, -0.2, 0.9, 0.1, 0.5], 4, 2.0),
            ([-0.7, 0.4, 0.2, -0.3, 0.8], 1, 0.0),
            ([0.5, 0.9, -0.6, 0.7, -0.1], 4, 1.0),
            ([-0.2, -0.8, -0.4, 0.6, 0.3], 0, 5.0),
        ];
        let mut grad = vec![0.0; params.len()];
        // Each row's relative weight, held constant as the gradient holds it.
        let mut weights = Vec::new();
        for (x, k, target) in &batch {
            let loss = SHAPE.gradient(&params, x, *k, *target, &mut grad);
            let q = SHAPE.forward(&params, x)[*k];
            weights.push(relative_weight(q) as f64);
            assert!((loss - 0.5 * (target - q).powi(2) * relative_weight(q)).abs() < 1e-5);
        }
        let loss_at = |p: &[f32]| -> f64 {
            batch
                .iter()
                .zip(&weights)
                .map(|((x, k, target), w)| {
                    let q = SHAPE.forward(p, x)[*k] as f64;
                    0.5 * (*target as f64 - q).powi(2) * w
                })
                .sum()
        };
        // Large enough that the f32 forward pass's rounding, which the relative
        // weight (up to 1 / epsilon) magnifies, stays below the tolerance.
        let h = 4e-3;
        let mut checked = 0;
        for i in 0..params.len() {
            let mut up = params.clone();
            let mut down = params.clone();
            up[i] += h;
            down[i] -= h;
            let numeric = ((loss_at(&up) - loss_at(&down)) / (2.0 * h as f64)) as f32;
            let tol = 2e-3 * numeric.abs().max(grad[i].abs()).max(0.1);
            assert!(
                (numeric - grad[i]).abs() <= tol,
                "parameter {i}: analytic {} numeric {numeric}",
                grad[i]
            );
            checked += (grad[i] != 0.0) as usize;
        }
        // Many parameters matter for this loss: the check is not vacuous.
        assert!(checked > params.len() / 3, "{checked} non-zero gradients");
    }

    #[test]
    fn adam_steps_downhill() {
        let mut params = SHAPE.init(5, 0.5);
        let x = [0.1, 0.2, -0.4, 0.8, 0.0];
        let (mut m, mut v) = (vec![0.0; params.len()], vec![0.0; params.len()]);
        let adam = Adam {
            learning_rate: 1e-2,
            ..Adam::default()
        };
        let mut first = None;
        let mut last = 0.0;
        for t in 1..=200 {
            let mut grad = vec![0.0; params.len()];
            last = SHAPE.gradient(&params, &x, 2, 3.0, &mut grad);
            first.get_or_insert(last);
            adam.step(&mut params, &mut m, &mut v, &grad, t);
        }
        assert!(last < 1e-3 * first.unwrap(), "{first:?} -> {last}");
    }
}
