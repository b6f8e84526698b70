"""Stand-in for distrax.Categorical (TFP, which distrax imports, does not load with this jax)."""
import jax
import jax.numpy as jnp


class Categorical:
    def __init__(self, logits):
        self.logits = logits
    def sample(self, seed):
        return jax.random.categorical(seed, self.logits, axis=-1)
    def log_prob(self, value):
        logp = jax.nn.log_softmax(self.logits, axis=-1)
        return jnp.take_along_axis(logp, value[..., None].astype(jnp.int32), axis=-1)[..., 0]
    def entropy(self):
        logp = jax.nn.log_softmax(self.logits, axis=-1)
        return -jnp.sum(jnp.exp(logp) * logp, axis=-1)
