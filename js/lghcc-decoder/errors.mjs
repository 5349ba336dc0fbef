// Error classes of spec clause 8.2 (the reference decoder's common/errors.py).
export class LghccError extends Error {
    constructor(message) { super(message); }
}
/** The stream is non-conforming (truncated, corrupted, or violating a constraint). ``condition``: the row of
 * clause 8.2's table it breaks ('E1' .. 'E68'), set where the check throws; undefined for a rejection that is no
 * row of it (a stream outside this decoder's profile). */
export class BitstreamError extends LghccError {
    constructor(message, condition) {
        super(message);
        this.condition = condition;
    }
}
/** Well formed as far as this decoder can tell, but uses a version, profile or unit it does not know. */
export class UnsupportedStreamError extends BitstreamError {}
/** Every unit decoded, but the decoded scene does not match scene_hash (clause 12). */
export class HashMismatchError extends BitstreamError {}
/** A conforming stream that needs more than this decoder is configured to hold (not a BitstreamError). */
export class ResourceLimitError extends LghccError {}

// names that survive minification (the worker bundle reports the class by name)
for (const [cls, name] of [[LghccError, 'LghccError'], [BitstreamError, 'BitstreamError'],
    [UnsupportedStreamError, 'UnsupportedStreamError'], [HashMismatchError, 'HashMismatchError'],
    [ResourceLimitError, 'ResourceLimitError']]) {
    Object.defineProperty(cls.prototype, 'name', { value: name });
}
