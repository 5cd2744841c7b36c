"""Learning a shape model from events: free trackers, then springs from co-activation.

    >>> import springtrack
    >>> model = springtrack.learn(events)                  # doctest: +SKIP
    >>> model = springtrack.learn(events, trackers=9)      # exactly 9 parts  # doctest: +SKIP

The paper's closing proposal ("the pool of trackers would then connect based on their
temporal coactivations"), in one pass over the learning window (docs/learning.md):

1. **A pool of free Gaussian trackers** (eqs. 2-6, no springs; per-event loop in
   ``learning/batch.pyx``) with a lifecycle every ``batch_us``:

   * *birth*: events no tracker takes (outside every gate, eq. 2) are counted, decayed
     with ``activity_tau_us``, in cells of ``birth_cell_px``; where a 3x3 block of cells
     holds ``birth_events`` of them and ``birth_contrast`` times the noise (the median
     block), a tracker is born with their mean and covariance;
   * *merge* (the union no wider than ``sigma_max_px``): duplicates (a share
     ``merge_overlap`` of the smaller one's events in both gates, one holding the other's
     mean), and the leading and trailing edges of one part, joined by pixels the part
     covers (:meth:`Pool.gaps`);
   * *death*: a tracker older than ``life_tau_us`` whose recent events fall below
     ``death_share`` of the pool's median, or below ``birth_contrast`` times the noise.

   The pass records each tracker's position, activity and events (:class:`History`).
2. **The final set**: established trackers with an extent, without the weak pieces and
   those their part left behind; ``trackers=N`` drops, merges or splits to N.
3. **Springs** between neighbours (the relative neighbourhood graph of the final
   positions and each tracker's three nearest) that were co-active (normalised inner
   product of their activity traces at least ``min_coactivation``) and kept their
   relative position in the object's frame (:func:`rigidity`); Cartesian where neither
   the pair nor the object turned by ``cartesian_turn_deg``, Euclidean + torsional
   otherwise.  Rest lengths and angles are those of the final positions (the model
   derives them from its positions, which are the positions at the window's end);
   stiffness ``stiffness_gain * alpha_1 * rigidity``; masses the trackers' event shares.
4. **Tracking parameters** learned from the same record: alpha_position
   (:func:`motion_alpha`), energy_scale (:func:`energy_scale`), energy_kind.

Deterministic: the same events and parameters give the same model.  Input without an
object raises :class:`NoObjectFound`.

Modules, by job: :mod:`.settings` (LearnParams, results, NoObjectFound), :mod:`.pool`
(the pool of free trackers, births), ``batch.pyx`` (its per-event loop), :mod:`.discovery`
(the pass and the final set), :mod:`.springs` (co-activation, rigidity), :mod:`.learner`
(``learn_model``, ``learn``, the model and its parameters).
"""
from .learner import learn, learn_model
from .settings import LearnParams, LearnResult, NoObjectFound

__all__ = ["learn", "learn_model", "LearnParams", "LearnResult", "NoObjectFound"]
